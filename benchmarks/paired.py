"""Paired whole-command timing of this checkout against a baseline checkout (issue 28's rows).

Each row of issue 28 is a script ``benchmarks/bench_speed_*.py`` that names the command a user
types and calls :func:`main` here.  The same command runs in two checkouts, each with its own
``.venv`` (``--baseline DIR``: a checkout of the main the issue was filed on, 7bdf681, with its
``./sappcw`` set-up done), alternately (A B, B A, A B, ... so that neither side always runs
first on a warm page cache), ``--repeats`` times each after one warm-up of each; the JSON gives
each side's wall times and peak memory (the largest resident set of the command and the
processes it waited for: ``ru_maxrss`` of ``os.wait4``), their medians, and the ratio
candidate / baseline of each pair with its median, so that a drift of the machine's speed during
the run cancels out.  The machine (CPU model, CPUs this process may use, load average before and
after) is noted.

    python benchmarks/bench_speed_campaign.py --baseline /path/to/checkout-7bdf681 [--repeats 3] [--bytecode]

The commands run in this process's environment.  Where it sets ``PYTHONDONTWRITEBYTECODE`` (as
the sessions of this project's machines and CI do), a checkout's commands read the bytecode its
set-up compiled (``./sappcw`` does since 2026-12-07; an older checkout's set-up compiled none, so
it compiles every module of its ``src/`` again in each command: about 0.12 s).  ``--bytecode``
gives both sides the same footing: Python's bytecode caches under a temporary
``PYTHONPYCACHEPREFIX``, filled by the warm-up runs (:func:`with_bytecode_cache`); the JSON's row
then ends in ``_with_bytecode_cache``.
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import platform
import shutil
import statistics
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]

#: A command to time, in a checkout ``root`` with a scratch directory ``tmp`` of its own per run:
#: (argv, extra environment).
Command = Callable[[Path, Path], tuple[list[str], dict[str, str]]]


def machine() -> dict[str, object]:
    """Where the figures were measured."""
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:
        cpus = os.cpu_count() or 1
    return {"platform": platform.platform(), "python": platform.python_version(), "cpu": cpu, "cpus": cpus}


def commit(root: Path) -> str:
    """The checkout's commit (and ``+changes`` when its tracked files differ from it)."""
    head = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True).stdout.strip()
    return head + ("+changes" if dirty else "")


def python_of(root: Path) -> str:
    """The checkout's own interpreter (its ``./sappcw`` set-up)."""
    py = root / ".venv" / "bin" / "python"
    if not py.is_file():
        raise SystemExit(f"{py} is missing: run ./sappcw --version in {root} first")
    return str(py)


def _timed(argv: list[str], env: dict[str, str], cwd: Path, timeout_s: float) -> tuple[float, float]:
    """(wall seconds, peak resident MB of the command and the processes it waited for) of one
    run; a failing command stops the benchmark with its output."""
    wall, usage = run_with_usage(argv, env, cwd, timeout_s)
    return wall, usage.ru_maxrss / 1024.0


def run_with_usage(argv: list[str], env: dict[str, str], cwd: Path, timeout_s: float) -> tuple[float, Any]:
    """(wall seconds, the OS's resource usage of this run alone: ``os.wait4``'s, its peak resident
    set ``ru_maxrss`` in KiB) of ``argv`` with ``env`` over this process's environment; a failing
    command stops the benchmark with its output."""
    with tempfile.TemporaryFile() as log:
        t0 = time.perf_counter()
        proc = subprocess.Popen(argv, cwd=cwd, env={**os.environ, **env}, stdout=log, stderr=subprocess.STDOUT)
        killer = threading.Timer(timeout_s, proc.kill)
        killer.start()
        try:
            _, status, usage = os.wait4(proc.pid, 0)  # the rusage of this run alone
        finally:
            killer.cancel()
        wall = time.perf_counter() - t0
        proc.returncode = code = os.waitstatus_to_exitcode(status)
        if code != 0:
            log.seek(0)
            why = f"was killed after {timeout_s} s" if wall >= timeout_s else f"exited {code}"
            raise SystemExit(f"{' '.join(argv)} {why}:\n{log.read().decode(errors='replace')[-3000:]}")
    return wall, usage


def _stats(xs: Sequence[float]) -> dict[str, float]:
    return {"median": statistics.median(xs), "min": min(xs), "max": max(xs)}


def paired(command: Command, baseline: Path, candidate: Path, repeats: int, timeout_s: float, warm_up: bool = True) -> dict[str, object]:
    """Both sides ``repeats`` times, alternately, after one warm-up each (``warm_up``)."""
    walls: dict[str, list[float]] = {"baseline": [], "candidate": []}
    peaks: dict[str, list[float]] = {"baseline": [], "candidate": []}
    roots = {"baseline": baseline, "candidate": candidate}
    first = 0 if warm_up else 1
    with tempfile.TemporaryDirectory(prefix="sappc-paired-") as tmp:
        for i in range(first, repeats + 1):
            order = ("baseline", "candidate") if i % 2 == 0 else ("candidate", "baseline")
            for side in order:
                scratch = Path(tmp) / f"{side}{i}"
                scratch.mkdir()
                argv, env = command(roots[side], scratch)
                wall, peak = _timed(argv, env, scratch, timeout_s)
                shutil.rmtree(scratch, ignore_errors=True)
                if i > 0:  # run 0 is the warm-up
                    walls[side].append(wall)
                    peaks[side].append(peak)
    ratios = [c / b for c, b in zip(walls["candidate"], walls["baseline"])]
    return {
        "wall_s": {side: {**_stats(w), "runs": w} for side, w in walls.items()},
        "peak_rss_mb": {side: _stats(p) for side, p in peaks.items()},
        "ratio_candidate_over_baseline": {**_stats(ratios), "runs": ratios},
    }


def with_bytecode_cache(row: str) -> str:
    """``--bytecode``: this process's environment set for both sides to keep and use Python's
    bytecode caches under a temporary ``PYTHONPYCACHEPREFIX`` (filled by the warm-up runs, removed
    at the end; the checkouts are not written to, and their own ``__pycache__`` are not read);
    returns the row's name for that."""
    cache = Path(tempfile.mkdtemp(prefix="sappc-bench-pycache-"))
    atexit.register(shutil.rmtree, cache, True)
    os.environ.update(PYTHONDONTWRITEBYTECODE="", PYTHONPYCACHEPREFIX=str(cache))
    return row + "_with_bytecode_cache"


def main(row: str, doc: str, command: Command, *, target: str, timeout_s: float = 600.0, repeats: int = 3,
         warm_command: Command | None = None) -> None:
    """Parse ``--baseline``/``--repeats``, time ``command`` on both sides and print the JSON.
    ``warm_command``: the same command on a warm cache, timed the same way after it (its warm-up
    run fills the cache); the JSON then has its times under ``"warm"`` and, per side, the
    difference of the medians, ``"cold_minus_warm_s"`` (what the cold cache cost: the compile)."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="a checkout of the baseline commit with its .venv set up")
    parser.add_argument("--repeats", type=int, default=repeats, help=f"counted runs of each side (default {repeats}; >= 3)")
    parser.add_argument("--no-warm-up", action="store_true",
                        help="no uncounted first run of each side (for commands of minutes, where a warm page cache is below the noise)")
    parser.add_argument("--bytecode", action="store_true",
                        help="both sides with Python's bytecode caches, kept under a temporary PYTHONPYCACHEPREFIX (module docstring)")
    args = parser.parse_args()
    if args.bytecode:
        row = with_bytecode_cache(row)
    baseline = args.baseline.resolve()
    for root in (baseline, ROOT):
        python_of(root)  # both set up, or a clear error now
    load_before = os.getloadavg()[0]
    result = paired(command, baseline, ROOT, max(1, args.repeats), timeout_s, warm_up=not args.no_warm_up)
    if warm_command is not None:
        warm = paired(warm_command, baseline, ROOT, max(1, args.repeats), timeout_s, warm_up=True)
        cold_wall, warm_wall = result["wall_s"], warm["wall_s"]
        assert isinstance(cold_wall, dict) and isinstance(warm_wall, dict)
        result = {**result, "warm": warm, "cold_minus_warm_s": {side: cold_wall[side]["median"] - warm_wall[side]["median"]
                                                                for side in ("baseline", "candidate")}}
    print(json.dumps({
        "row": row,
        "target": target,
        "date": time.strftime("%Y-%m-%d"),
        "machine": machine(),
        "load_average_1min": {"before": load_before, "after": os.getloadavg()[0]},
        "baseline": {"root": str(baseline), "commit": commit(baseline)},
        "candidate": {"root": str(ROOT), "commit": commit(ROOT)},
        "repeats": args.repeats,
        "warm_up": not args.no_warm_up,
        **result,
    }, indent=2))

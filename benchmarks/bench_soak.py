"""Soak of the real-time graph: the controller's memory over a long run (issue: the graph, target
"controller memory over a 600 s real-time run: flat, < 0.5 MiB").

Runs experiment 1 (``config/scenarios/paper_tracking.yaml``) in real time for ``--duration-s``
seconds (default 600) through ``sappc run --realtime`` (five processes, recorder included) and
samples the controller process's resident memory (``VmRSS`` of ``/proc/<pid>/status``) every
``--every-s`` seconds.  Prints one JSON document: the samples, the growth from the first sample
after ``--warm-s`` (imports, compile-cache load, discovery) to the end, the least-squares slope
over that span [MiB/h], and the run's real-time figures (frames, stale torques, latency).

    python benchmarks/bench_soak.py [--duration-s 600] [--every-s 5] [--warm-s 60] [--domain-id N]

Linux only (``/proc``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from sappc.graph.launch import run_graph  # noqa: E402

SCENARIO = ROOT / "config" / "scenarios" / "paper_tracking.yaml"


def _controller_pid(run_dir: Path) -> int | None:
    """The controller process of the run in ``run_dir`` (its working directory), if it is up."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
            if any(b"sappc_controller" in part for part in cmdline) and Path(os.readlink(entry / "cwd")) == run_dir.resolve():
                return int(entry.name)
        except OSError:
            continue
    return None


def _rss_kib(pid: int) -> int | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration-s", type=float, default=600.0)
    parser.add_argument("--every-s", type=float, default=5.0)
    parser.add_argument("--warm-s", type=float, default=60.0)
    parser.add_argument("--domain-id", type=int, default=None)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        scenario = yaml.safe_load(SCENARIO.read_text())
        scenario["duration_s"] = args.duration_s
        path = Path(tmp) / "soak.yaml"
        path.write_text(yaml.safe_dump(scenario))
        run_dir = Path(tmp) / "run"
        samples: list[tuple[float, int]] = []  # (s since the controller was found, RSS KiB)
        done = threading.Event()

        def sample() -> None:
            pid, t0 = None, 0.0
            while not done.is_set():
                if pid is None and run_dir.exists():
                    pid = _controller_pid(run_dir)
                    t0 = time.monotonic()
                if pid is not None and (rss := _rss_kib(pid)) is not None:
                    samples.append((time.monotonic() - t0, rss))
                done.wait(args.every_s if pid is not None else 0.2)

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        try:
            result = run_graph(path, out_dir=run_dir, realtime=True, progress=False, domain_id=args.domain_id)
        finally:
            done.set()
            sampler.join()
        t = np.array([s[0] for s in samples])
        rss_mib = np.array([s[1] for s in samples]) / 1024.0
        warm = t >= args.warm_s
        slope = float(np.polyfit(t[warm], rss_mib[warm], 1)[0] * 3600.0) if warm.sum() >= 2 else float("nan")
        print(json.dumps({
            "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count(),
                        "load_average_1min_after": os.getloadavg()[0]},
            "duration_s": args.duration_s,
            "controller_rss_mib": {"first": float(rss_mib[0]) if rss_mib.size else None,
                                   "after_warm_up": float(rss_mib[warm][0]) if warm.any() else None,
                                   "last": float(rss_mib[-1]) if rss_mib.size else None,
                                   "growth_after_warm_up": float(rss_mib[warm][-1] - rss_mib[warm][0]) if warm.any() else None,
                                   "slope_mib_per_hour": slope,
                                   "samples": [[round(a, 1), round(b, 3)] for a, b in zip(t.tolist(), rss_mib.tolist())]},
            "target_growth_mib": 0.5,
            "plant": {k: result.plant_timing.get(k) for k in ("ticks", "period_error_p99_ms", "missed_ticks", "missed_frames", "stale_torque_frames")},
            "controller_latency": result.controller_timing.get("latency", {}),
        }, indent=2))


if __name__ == "__main__":
    main()

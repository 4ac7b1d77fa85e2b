"""The recorder's peak memory over a long lockstep run, and whether rosbags reads every message of it.

Issue 25's "done means": a 10-minute lockstep run records with the recorder's peak memory
<= 200 MB, and rosbags reads every message of it.  This runs ``sappc run`` (five processes) on a
temporary copy of ``config/scenarios/paper_tracking.yaml`` with ``duration_s`` = ``--duration-s``
(600 by default: 60,001 samples, about 660,000 messages), then:

- the recorder's peak resident memory, two ways: its own figure, the kernel's high-water mark of
  its resident set (``VmHWM`` of ``/proc/self/status``) read once it closed the bag (the closing
  sort included), from its log's closing line; and the largest ``VmHWM`` read from
  ``/proc/<pid>/status`` every :data:`POLL_S` while it ran (a cross-check that misses the last
  half second);
- the messages each node published, those the recorder counted, and those ``rosbags``
  (``AnyReader``, every message deserialised) reads from the bag directory;
- how far the recorder's writer thread fell behind its taking thread (messages), from the same
  log line, and the machine (CPU model, cores, Python).

Prints one JSON object.  Not a test (about three minutes of wall time for 600 s here).

    python benchmarks/bench_recorder_memory.py [--duration-s 600] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
#: The scenario the run is a longer copy of.
SCENARIO = ROOT / "config" / "scenarios" / "paper_tracking.yaml"
#: Period of the /proc/<pid>/status reading [s].
POLL_S = 0.5
#: The issue's bound on the recorder's peak memory [MB].
BOUND_MB = 200.0
#: The recorder's closing log line (sappc.graph.recorder.RecorderNode.finish).
CLOSING = re.compile(r"closed: (\d+) messages; the writer thread was at most (\d+) messages behind; peak memory ([\d.]+) MiB")


def _children(pid: int) -> list[int]:
    try:
        return [int(p) for p in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except FileNotFoundError:
        return []


def _vm_hwm_kib(pid: int) -> int | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except FileNotFoundError:
        return None
    return None


def _rosbags_count(bag_dir: Path) -> dict[str, int]:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    counts: dict[str, int] = {}
    with AnyReader([bag_dir], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, _, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
    return counts


def _cpu_model() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor()


def main() -> int:
    cli = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    cli.add_argument("--duration-s", type=float, default=600.0, help="simulated length of the run [s] (default 600)")
    cli.add_argument("--keep", metavar="DIR", help="run in DIR and keep it (default: a temporary directory, removed)")
    args = cli.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_recorder_memory-") as tmp_name:
        tmp = Path(args.keep) if args.keep else Path(tmp_name)
        tmp.mkdir(parents=True, exist_ok=True)
        scenario = yaml.safe_load(SCENARIO.read_text())
        scenario["duration_s"] = args.duration_s
        path = tmp / "long.yaml"
        path.write_text(yaml.safe_dump(scenario, sort_keys=False))
        out, summary = tmp / "run", tmp / "run.json"
        start = time.monotonic()
        run = subprocess.Popen([sys.executable, "-m", "sappc", "run", str(path), "--out", str(out), "--json", str(summary)],
                               cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        recorder: int | None = None
        hwm_kib = 0
        while run.poll() is None:
            if recorder is None:
                recorder = next((p for p in _children(run.pid) if "sappc.graph.recorder" in Path(f"/proc/{p}/cmdline").read_text(errors="replace")),
                                None)
            if recorder is not None:
                hwm_kib = max(hwm_kib, _vm_hwm_kib(recorder) or 0)
            time.sleep(POLL_S)
        output = run.communicate()[0]
        wall_s = time.monotonic() - start
        if run.returncode != 0:
            print(output, file=sys.stderr)
            print(json.dumps({"failed": run.returncode, "recorder_vmhwm_mib_polled": round(hwm_kib / 1024, 1), "wall_s": round(wall_s, 1)}))
            return run.returncode
        result = json.loads(summary.read_text())
        log = (out / "logs" / "recorder.log").read_text()
        closing = CLOSING.search(log)
        assert closing is not None, log[-2000:]
        read = _rosbags_count(out / "bag")
        peak_mib = float(closing.group(3))
        report = {
            "scenario": f"{SCENARIO.name} with duration_s {args.duration_s:g}",
            "samples": int(round(args.duration_s / scenario["control_period_s"])) + 1,
            "messages_published": sum(result["published"].values()),
            "messages_recorded": sum(result["recorded"].values()),
            "messages_read_by_rosbags": sum(read.values()),
            "rosbags_reads_every_message": read == {t: n for t, n in result["recorded"].items() if n},
            "recorder_peak_rss_mib": peak_mib,
            "recorder_peak_rss_mb": round(peak_mib * 1.048576, 1),
            "recorder_vmhwm_mib_polled": round(hwm_kib / 1024, 1),
            "bound_mb": BOUND_MB,
            "within_bound": peak_mib * 1.048576 <= BOUND_MB,
            "writer_max_backlog_messages": int(closing.group(2)),
            "bag_bytes": sum(f.stat().st_size for f in (out / "bag").iterdir()),
            "wall_s": round(wall_s, 1),
            "machine": {"cpu": _cpu_model(), "cores": os.cpu_count(), "python": platform.python_version(), "system": platform.platform()},
        }
    print(json.dumps(report, indent=1))
    return 0 if report["within_bound"] and report["rosbags_reads_every_message"] else 1


if __name__ == "__main__":
    sys.exit(main())

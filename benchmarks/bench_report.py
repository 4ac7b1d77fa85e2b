"""Benchmark of bag analysis (issue: replay and analysis, "Done means").

On a 60 s, 100 Hz bag of experiment 1 (recorded with ``sappc run`` unless ``--bag`` is given),
prints one JSON document:

- ``report``: the wall time of the whole ``sappc report BAG --out DIR`` command as a user runs it
  (a fresh process: interpreter start, imports, reading, metrics, five figures, the HTML page),
  median of ``--repeats`` runs; target <= 2 s;
- ``reading``: messages per second of :func:`sappc.bag.read.read_bag` (scan and decode every
  message of the contract), median of ``--repeats`` runs; target >= 100,000 messages/s; with,
  measured in the same run as baselines, the ``mcap`` package's ``StreamReader`` alone (records
  only, no decoding) and ``StreamReader`` plus ``rclpy`` deserialisation (the previous reader).

    python benchmarks/bench_report.py [--repeats 5] [--bag DIR]
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

from sappc.bag.read import mcap_file, read_bag  # noqa: E402

SCENARIO = ROOT / "config" / "scenarios" / "paper_tracking.yaml"


def _stream_reader(path: Path, decode: bool) -> int:
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    classes = {}
    if decode:
        from rclpy.serialization import deserialize_message

        from sappc_msgs_py.contract import Topic
    schemas: dict[int, str] = {}
    n = 0
    with open(path, "rb") as f:
        for record in StreamReader(f).records:
            if isinstance(record, Message):
                if decode:
                    deserialize_message(record.data, classes[record.channel_id])
                n += 1
            elif isinstance(record, Schema):
                schemas[record.id] = record.name
            elif isinstance(record, Channel) and decode:
                classes[record.id] = Topic(record.topic, schemas[record.schema_id], None).msg_class
    return n


def _median_rate(fn, repeats: int) -> tuple[float, int]:  # type: ignore[no-untyped-def]
    rates, n = [], 0
    for _ in range(repeats):
        t = time.perf_counter()
        n = fn()
        rates.append(n / (time.perf_counter() - t))
    return statistics.median(rates), n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--bag", type=Path, help="a recorded 60 s bag (default: record experiment 1 now)")
    args = parser.parse_args()
    out: dict[str, object] = {"machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count()}}
    with tempfile.TemporaryDirectory() as tmp:
        bag = args.bag
        if bag is None:
            from sappc.graph.launch import run_graph

            bag = run_graph(SCENARIO, out_dir=Path(tmp) / "run", progress=False).bag_dir
        out["bag"] = str(bag)
        times = []
        for i in range(args.repeats):
            t = time.perf_counter()
            proc = subprocess.run([sys.executable, "-m", "sappc", "report", str(bag), "--out", str(Path(tmp) / f"report{i}")],
                                  capture_output=True, text=True, cwd=ROOT)
            times.append(time.perf_counter() - t)
            if proc.returncode != 0:
                raise SystemExit(proc.stdout + proc.stderr)
        out["report"] = {"wall_s": times, "wall_s_median": statistics.median(times), "target_s": 2.0}
        rate, n = _median_rate(lambda: sum(read_bag(bag).counts.values()), args.repeats)
        mcap = mcap_file(Path(bag))
        raw_rate, _ = _median_rate(lambda: _stream_reader(mcap, decode=False), args.repeats)
        rclpy_rate, _ = _median_rate(lambda: _stream_reader(mcap, decode=True), max(1, args.repeats // 2))
        out["reading"] = {
            "messages": n,
            "read_bag_msgs_per_s": rate,
            "baseline_mcap_stream_reader_msgs_per_s": raw_rate,
            "baseline_stream_reader_plus_rclpy_msgs_per_s": rclpy_rate,
            "speedup_vs_stream_reader_plus_rclpy": rate / rclpy_rate,
            "target_msgs_per_s": 100_000,
        }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()

"""Issue 47, item 6: the peak memory of ``sappc report`` on a long bag, from the OS.

    python benchmarks/bench_bag_memory.py [--source BAG] [--samples 6000,60000,567701] [--offline-orbit] [--repeats 3] [--baseline DIR]

The bag: a short bag of the graph (``--source``; by default a 2 s arc of ``paper_tracking_orbit``
recorded by ``sappc run`` in lockstep, as ``tests/tools/graph/test_orbit_graph.py`` flies it:
every topic of the orbit scenario, 29 messages a sample) tiled end to end into a bag of each
length of ``--samples`` (:func:`tile_bag`: copy ``c`` of every message, its stamps and log time
shifted by ``c`` times the source's span; the payloads as recorded, the header stamp and a float
array's time rewritten, written with the recorder's writer, chunk size and compression).  One
orbit is 567,701 samples, the length of the graph's 756 MB bag (16.5 million messages); the
tiled bag has its messages and their sizes, its values repeat every 2 s (a chunk holds 0.65 s: it
compresses as the recorded one does).

``--offline-orbit``: also one orbit of ``paper_tracking_orbit`` flown offline and recorded as the
graph's bag (:func:`offline_orbit_bag`: 567,701 samples, 13.6 million messages, 684 MB in about
15 s), the baseline reading it too (about 6.3 GB).

Each measurement is ``sappc report BAG --out DIR --json FILE`` in a child process of its own
(``python -m sappc``; its figure process included: ``ru_maxrss`` of ``os.wait4`` is the largest
resident set of the command and of the processes it waited for), its user and system CPU time and
wall time; the medians of ``--repeats`` runs, after one uncounted warm-up run of each side and
length.  The report's JSON (metrics, per-orbit table, counts) is hashed: equal hashes between
two checkouts are the same numbers bit for bit.

``--baseline DIR``: also run each length in the checkout DIR (``git archive COMMIT | tar -x -C
DIR``: it runs with this checkout's ``.venv`` and ``PYTHONPATH=DIR/src``), alternately with this
one; lengths above ``--baseline-max-samples`` are not run on the baseline (the whole bag in memory:
7.9 GB for one orbit).  Each side's peak is fitted as ``a + b m`` over the lengths' message
counts ``m`` (least squares), and extrapolated to the orbit's 16.5 million messages.

Prints one JSON document (``machine``: where it was measured; save it under
``benchmarks/results_memory/``).
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
import paired  # noqa: E402

#: The source arc flown by default [s]: test_orbit_graph.py's (201 samples, every orbit topic).
ARC_S = 2.0
#: One orbit of ``paper_tracking_orbit`` [s] (94.6 min) and its samples at 100 Hz: the graph's 756 MB bag.
ORBIT_S = 5677.0
ORBIT_SAMPLES = 567_701
#: The messages of that bag (docs/how-to/momentum.md, "One orbit on the graph").
ORBIT_MESSAGES = 16_500_000
DEFAULT_SAMPLES = (6_000, 60_000, 200_000, ORBIT_SAMPLES)
#: The baseline (the whole bag in memory) is run up to this length by default: 200,000 samples
#: (5.8 million messages) took about 3 GB before item 6.
BASELINE_MAX_SAMPLES = 200_000
#: The longest a report may run [s].
REPORT_TIMEOUT_S = 1800.0
#: Keys of the report's JSON that vary from run to run (none of the numbers: the paths).
_UNSTABLE = ("bag",)


def record_source(work: Path) -> Path:
    """A 2 s arc of ``paper_tracking_orbit`` through ``sappc run`` in lockstep (its bag)."""
    import yaml

    sys.path.insert(0, str(ROOT / "tests"))
    from conftest import cut_short  # the tests' cut: no requirements for a run cut short

    from sappc.scenario import load_scenario

    out = work / "source"
    if (out / "bag").is_dir():
        return out / "bag"
    raw = copy.deepcopy(load_scenario(ROOT / "config" / "scenarios" / "paper_tracking_orbit.yaml").raw)
    cut_short(raw, ARC_S)
    raw["metrics"]["steady_from_s"] = ARC_S / 2
    raw["momentum_management"].update(replan_s=0.5, plan_step_s=0.5, horizon_s=300.0)  # as test_orbit_graph: four plans in the arc
    scenario = work / "arc.yaml"
    scenario.write_text(yaml.safe_dump(raw))
    proc = subprocess.run([sys.executable, "-m", "sappc", "run", str(scenario), "--out", str(out)], capture_output=True, text=True, cwd=ROOT)
    if proc.returncode not in (0, 4):  # 4: a requirement failed (a cut run), the bag is whole
        raise SystemExit(f"sappc run failed ({proc.returncode}):\n{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
    return out / "bag"


#: The controller diagnostics' rows of stamps [s] (3 values a row): the inputs each step used.
_INPUT_STAMP_ROWS = ("input_stamps_state_s", "input_stamps_reference_s")


def _stamp_writers(schema: str, payload: bytes) -> list[tuple[int, str]]:
    """Where a message of ``schema`` carries a stamp: (byte offset, "time" for a header's or a
    clock's int32 sec and uint32 nanosec, "seconds" for a float array's ``data[0]`` in seconds,
    "input seconds" for the diagnostics' input stamps, in seconds, a zero there, no step, kept)."""
    from sappc.bag.cdr import _parse_multiarray
    from sappc_msgs_py.contract import float_array_carries_time

    if schema == "std_msgs/msg/Float64MultiArray":
        labels, data_at, count, _ = _parse_multiarray(payload)
        if not (labels and float_array_carries_time(labels[0]) and count):
            return []
        names = labels[0].split(",")
        rows = [3 * names.index(r) + j for r in _INPUT_STAMP_ROWS if r in names for j in range(3)]
        return [(data_at, "seconds")] + [(data_at + 8 * i, "input seconds") for i in rows if i < count]
    return [(4, "time")]  # the header's stamp (every other type of the contract), or the clock's


def tile_bag(source: Path, out: Path, samples: int) -> dict[str, Any]:
    """Write ``out`` (an .mcap file): the messages of ``source`` repeated until the bag has
    ``samples`` state samples, copy ``c`` shifted by ``c`` times the source's span (its log times'
    and stamps'); the metadata records of ``source`` once.  Returns its size and counts."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    from sappc.bag.read import mcap_file
    from sappc.graph.recorder import CHUNK_SIZE

    with open(mcap_file(source), "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        messages = [(ch.id, msg.log_time, msg.data) for _, ch, msg in reader.iter_messages(log_time_order=False)]
        metadata = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
    schemas, channels = summary.schemas, summary.channels
    state = next(c.id for c in channels.values() if c.topic.endswith("/state/attitude"))
    per_copy = sum(1 for cid, _, _ in messages if cid == state)
    logs = np.array([t for _, t, _ in messages], dtype=np.int64)
    state_logs = np.array([t for cid, t, _ in messages if cid == state], dtype=np.int64)
    dt_ns = int(np.median(np.diff(state_logs)))
    period_ns = int(logs.max() - logs.min()) + dt_ns
    copies = -(-samples // per_copy)
    where = {cid: _stamp_writers(schemas[channels[cid].schema_id].name, data) for cid, _, data in messages}
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "wb") as f:
        w = Writer(f, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        w.start(profile="ros2", library="benchmarks/bench_bag_memory.py (tiled)")
        sid = {k: w.register_schema(s.name, s.encoding, s.data) for k, s in schemas.items()}
        cid_of = {k: w.register_channel(c.topic, c.message_encoding, sid[c.schema_id], dict(c.metadata)) for k, c in channels.items()}
        for name, data in metadata:
            w.add_metadata(name, data)
        count = 0
        for c in range(copies):
            shift = c * period_ns
            for cid, log, data in messages:
                buf = bytearray(data)
                for at, kind in where[cid]:
                    if kind == "time":
                        ns = int.from_bytes(buf[at : at + 4], "little", signed=True) * 1_000_000_000 + int.from_bytes(buf[at + 4 : at + 8], "little")
                        sec, nsec = divmod(ns + shift, 1_000_000_000)
                        buf[at : at + 8] = sec.to_bytes(4, "little", signed=True) + nsec.to_bytes(4, "little")
                    else:
                        seconds = float(np.frombuffer(bytes(buf[at : at + 8]), "<f8")[0])
                        if kind == "seconds" or (seconds != 0.0 and np.isfinite(seconds)):  # an input stamp 0: no step
                            buf[at : at + 8] = np.float64((round(seconds * 1e9) + shift) / 1e9).tobytes()
                w.add_message(cid_of[cid], log_time=log + shift, data=bytes(buf), publish_time=log + shift)
                count += 1
        w.finish()
    return {"bag": str(out), "bytes": out.stat().st_size, "messages": count, "copies": copies, "samples": copies * per_copy,
            "source_messages_per_sample": len(messages) / per_copy}


def offline_orbit_bag(out: Path, duration_s: float = ORBIT_S) -> dict[str, Any]:
    """One orbit of ``paper_tracking_orbit`` flown offline and recorded as the graph's bag
    (:class:`~sappc.bag.write_offline.OfflineBagWriter`, ``sappc simulate --record``: the lockstep
    recorder's topics, types and stamps but the sensors' measurements, which the record does not
    hold): a bag of one orbit's real values in seconds.  Returns its size and counts."""
    from sappc.bag.write_offline import OfflineBagWriter
    from sappc.offline.simulate import simulate
    from sappc.scenario import load_scenario, scenario_from_mapping

    raw = copy.deepcopy(load_scenario(ROOT / "config" / "scenarios" / "paper_tracking_orbit.yaml").raw)
    raw["duration_s"] = duration_s
    scenario = scenario_from_mapping(raw)
    with OfflineBagWriter(scenario, out) as writer:
        simulate(scenario, None, history="none", sinks=(writer,))
    mcap = out / writer.mcap_name
    messages = writer.samples * len(writer.channels)
    return {"bag": str(out), "bytes": mcap.stat().st_size, "messages": messages, "samples": writer.samples,
            "source_messages_per_sample": len(writer.channels)}


def _made_in_a_child(source: Path, bag: Path, samples: int) -> dict[str, Any]:
    """:func:`tile_bag` (``samples`` > 0) or :func:`offline_orbit_bag` (0) in a child process: the
    benchmark's own process stays small, for the OS counts the resident set a measured command
    had before its ``exec`` (the benchmark's, forked) in its peak (a 576 MB peak measured for a
    301 MB report after the orbit had been flown in this process)."""
    code = ("import json, sys; from pathlib import Path; sys.path.insert(0, sys.argv[1]); import bench_bag_memory as b; "
            "n = int(sys.argv[4]); print(json.dumps(b.tile_bag(Path(sys.argv[2]), Path(sys.argv[3]), n) if n else b.offline_orbit_bag(Path(sys.argv[3]))))")
    proc = subprocess.run([sys.executable, "-c", code, str(Path(__file__).resolve().parent), str(source), str(bag), str(samples)],
                          capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    if proc.returncode != 0:
        raise SystemExit(f"making {bag} failed:\n{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
    made: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return made


def _digest(report: dict[str, Any]) -> str:
    """sha256 of the report's JSON but its paths: metrics, per-orbit table, counts, notes."""
    doc = {k: v for k, v in report.items() if k not in _UNSTABLE}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


def run_report(root: Path, bag: Path, tmp: Path) -> dict[str, Any]:
    """One ``sappc report`` of ``bag`` with checkout ``root``: peak RSS [MB], CPU and wall [s], the
    JSON's hash and ``steady_max_abs_qev``."""
    out, js = tmp / "report", tmp / "report.json"
    argv = [sys.executable, "-m", "sappc", "report", str(bag), "--out", str(out), "--json", str(js)]
    wall, usage = paired.run_with_usage(argv, {"PYTHONPATH": str(root / "src")}, tmp, REPORT_TIMEOUT_S)
    report = json.loads(js.read_text())
    subprocess.run(["rm", "-rf", str(out), str(js)], check=True)
    return {"peak_rss_mb": usage.ru_maxrss / 1024.0, "user_s": usage.ru_utime, "sys_s": usage.ru_stime, "cpu_s": usage.ru_utime + usage.ru_stime,
            "wall_s": wall, "digest": _digest(report), "samples": report["samples"],
            "read_in_blocks": not any(n.startswith("the bag was read whole") for n in report.get("notes", [])),
            "steady_max_abs_qev": (report.get("metrics") or {}).get("steady_max_abs_qev")}


def _fit(points: list[tuple[int, float]]) -> dict[str, float] | None:
    """Least squares ``peak_mb = a + b m`` over (messages, peak MB): a [MB], b [bytes a message], and
    the peak extrapolated to :data:`ORBIT_MESSAGES` [MB]."""
    if len({m for m, _ in points}) < 2:
        return None
    m = np.array([p[0] for p in points], dtype=np.float64)
    y = np.array([p[1] for p in points], dtype=np.float64)
    b, a = np.polyfit(m, y, 1)
    return {"intercept_mb": float(a), "bytes_per_message": float(b * 2**20), "orbit_16.5M_messages_mb": float(a + b * ORBIT_MESSAGES)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", type=Path, help="a short bag of the graph to tile (default: record a 2 s orbit arc)")
    parser.add_argument("--samples", default=",".join(map(str, DEFAULT_SAMPLES)), help="comma-separated bag lengths [samples]")
    parser.add_argument("--repeats", type=int, default=3, help="counted runs of each length and side (default 3)")
    parser.add_argument("--baseline", type=Path, help="a checkout to pair against (run with this checkout's .venv)")
    parser.add_argument("--baseline-commit", default="", help="the baseline's commit, when DIR is an export (no .git)")
    parser.add_argument("--candidate-commit", default="", help="this checkout's commit, when it is an export (no .git)")
    parser.add_argument("--baseline-max-samples", type=int, default=BASELINE_MAX_SAMPLES, help="longest bag the baseline reads")
    parser.add_argument("--work", type=Path, help="where the bags are written and kept (default: a temporary directory)")
    parser.add_argument("--offline-orbit", action="store_true",
                        help="also one orbit flown offline and recorded as a bag (sappc simulate --record); the baseline reads it too")
    args = parser.parse_args()
    lengths = [int(s) for s in args.samples.split(",") if s.strip()]
    roots = {"candidate": ROOT} if args.baseline is None else {"baseline": args.baseline.resolve(), "candidate": ROOT}
    head: dict[str, Any] = {
        "issue": 47, "item": 6, "date": time.strftime("%Y-%m-%d"), "machine": paired.machine(),
        "memory_total_gb": os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30,
        "load_average_1min_before": os.getloadavg()[0], "command": "sappc report BAG --out DIR --json FILE",
        **{side: {"root": str(root), "commit": paired.commit(root) if (root / ".git").exists()
                  else f"export of {(args.baseline_commit if side == 'baseline' else args.candidate_commit) or '?'}"}
           for side, root in roots.items()},
    }
    with tempfile.TemporaryDirectory(prefix="sappc-bagmem-") as tmp_s:
        work = args.work or Path(tmp_s)
        work.mkdir(parents=True, exist_ok=True)
        source = args.source or record_source(work) if lengths else Path()
        cases: dict[str, Any] = {}
        todo: list[tuple[str, int]] = [(f"tiled_{n}", n) for n in lengths] + ([("offline_orbit", 0)] if args.offline_orbit else [])
        for name, n in todo:
            bag = work / (f"{name}.mcap" if n else name)
            t0 = time.perf_counter()
            subprocess.run(["rm", "-rf", str(bag)], check=True)
            made = _made_in_a_child(source, bag, n)
            made["write_s"] = time.perf_counter() - t0
            print(f"{name}: {made['samples']} samples, {made['messages']} messages, {made['bytes'] / 1e6:.1f} MB ({made['write_s']:.0f} s to write)",
                  file=sys.stderr, flush=True)
            sides = [s for s in roots if s == "candidate" or not n or n <= args.baseline_max_samples]
            runs: dict[str, list[dict[str, Any]]] = {s: [] for s in sides}
            for i in range(args.repeats + 1):  # run 0: the warm-up
                for side in (sides if i % 2 == 0 else list(reversed(sides))):
                    scratch = Path(tempfile.mkdtemp(dir=tmp_s))
                    r = run_report(roots[side], bag, scratch)
                    print(f"  {side} {'warm-up' if i == 0 else i}: {r['peak_rss_mb']:.0f} MB, cpu {r['cpu_s']:.1f} s, wall {r['wall_s']:.1f} s",
                          file=sys.stderr, flush=True)
                    if i > 0:
                        runs[side].append(r)
            case: dict[str, Any] = {"bag": {k: v for k, v in made.items() if k != "bag"}}
            for side, rs in runs.items():
                case[side] = {**{f"{k}_median": statistics.median(r[k] for r in rs) for k in ("peak_rss_mb", "cpu_s", "user_s", "sys_s", "wall_s")},
                              "digests": sorted({r["digest"] for r in rs}), "steady_max_abs_qev": rs[0]["steady_max_abs_qev"],
                              "read_in_blocks": all(r["read_in_blocks"] for r in rs), "runs": rs}
            if len(runs) == 2:
                case["same_numbers"] = case["candidate"]["digests"] == case["baseline"]["digests"]
            cases[name] = case
            if args.work is None:
                subprocess.run(["rm", "-rf", str(bag)], check=True)
    fits = {side: _fit([(c["bag"]["messages"], c[side]["peak_rss_mb_median"]) for name, c in cases.items() if side in c and name.startswith("tiled")])
            for side in roots}
    print(json.dumps({**head, "repeats": args.repeats, "cases": cases, "fit_peak_over_messages": fits,
                      "load_average_1min_after": os.getloadavg()[0]}, indent=2))


if __name__ == "__main__":
    main()

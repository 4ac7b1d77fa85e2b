"""The loop time of ``sappc run`` with and without ``--live`` (issue 51: within 10 %).

Runs ``sappc run SCENARIO`` (lockstep, five processes, or ``--compose``) ``--pairs`` times in each
of three ways, alternating within each round: without ``--live``; with ``--live 0`` and no client;
with ``--live 0 --wait-subscribers 1`` and a client of the Foxglove WebSocket protocol subscribed
to every channel for the whole run (it reads every message it is sent, in a thread of this
process, and each is then looked up in the run's bag: every topic received, every message's
log time and bytes the bag's).  The loop time is the run's ``wall_time_s`` (the plant's first sample to its last, from
``--json``).  Writes JSON: each run's loop time (and the client's message count), the medians and
the ratios of the medians to the run without ``--live``, the machine and its load average before
and after.

    .venv/bin/python benchmarks/bench_live_run.py config/scenarios/paper_tracking_flight.yaml \\
        --out benchmarks/results_speed/live_run.json
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = ("plain", "live_no_client", "live_client")


def _client(url: str, counts: dict[str, int], received: dict[str, list[tuple[int, bytes]]]) -> None:
    """Subscribe to every channel and read until the run's verdict or the server's end; keep each
    message's (timestamp, payload) by topic in ``received``."""
    import websockets

    async def watch() -> None:
        async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"], max_size=None, open_timeout=300) as ws:
            channels: dict[int, dict[str, Any]] = {}
            subscribed = False
            try:
                while True:
                    message = await asyncio.wait_for(ws.recv(), 600)
                    if isinstance(message, str):
                        data = json.loads(message)
                        if data["op"] == "advertise":
                            channels.update({c["id"]: c for c in data["channels"]})
                            if not subscribed and any(c["topic"] == "/sappc/run" for c in channels.values()):
                                subscribed = True
                                await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": c}
                                                                                                for i, c in enumerate(channels)]}))
                    elif message[0] == 0x01:  # message data: opcode, subscription id u32, timestamp u64, payload
                        counts["messages"] += 1
                        sub = int.from_bytes(message[1:5], "little")
                        topic = channels[list(channels)[sub]]["topic"]
                        received.setdefault(topic, []).append((int.from_bytes(message[5:13], "little"), bytes(message[13:])))
                        if b'"phase": "verdict"' in message[13:]:
                            return
            except websockets.ConnectionClosed:
                return

    asyncio.run(watch())


def _compare(bag: Path, received: dict[str, list[tuple[int, bytes]]]) -> dict[str, Any]:
    """The client's messages against the bag (issue 51's "Done means"): the bag's topics the client
    received none of, and the received messages whose (log time, bytes) the bag's topic does not hold."""
    from mcap.reader import make_reader

    in_bag: dict[str, set[tuple[int, bytes]]] = {}
    [path] = sorted(bag.glob("*.mcap"))
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            in_bag.setdefault(channel.topic, set()).add((message.log_time, bytes(message.data)))
    got = {t: m for t, m in received.items() if t in in_bag}
    return {"bag_topics": len(in_bag), "bag_topics_received": sum(1 for t in in_bag if got.get(t)),
            "topics_not_received": sorted(t for t in in_bag if not got.get(t)),
            "received_bag_messages": sum(len(m) for m in got.values()),
            "received_not_in_bag": sum(1 for t, m in got.items() for x in m if x not in in_bag[t]),
            "other_topics_received": sorted(t for t in received if t not in in_bag)}


def one_run(scenario: str, variant: str, compose: bool, workdir: Path) -> dict[str, Any]:
    out = workdir / f"{variant}-{time.monotonic_ns()}"
    cmd = [sys.executable, "-m", "sappc", "run", scenario, "--out", str(out), "--json", str(out) + ".json"]
    cmd += ["--compose"] if compose else []
    cmd += {"plain": [], "live_no_client": ["--live", "0"], "live_client": ["--live", "0", "--wait-subscribers", "1"]}[variant]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    counts = {"messages": 0}
    received: dict[str, list[tuple[int, bytes]]] = {}
    client: threading.Thread | None = None
    assert proc.stderr is not None
    for line in proc.stderr:
        m = re.search(r"live view at (ws://\S+)", line)
        if m and variant == "live_client" and client is None:
            client = threading.Thread(target=_client, args=(m.group(1), counts, received), daemon=True)
            client.start()
    rc = proc.wait()
    if client is not None:
        client.join(60)
    report = json.loads(Path(str(out) + ".json").read_text())
    row = {"variant": variant, "exit_status": rc, "wall_time_s": report["metrics"]["wall_time_s"],
           "messages_recorded": sum(report["recorded"].values())}
    if variant == "live_client":
        row["client_messages"] = counts["messages"]
        row.update(_compare(out / "bag", received))
    print(json.dumps(row), file=sys.stderr, flush=True)
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenario")
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--compose", action="store_true")
    ap.add_argument("--out", default=None, help="the JSON file (default: stdout)")
    args = ap.parse_args()
    load_before = os.getloadavg()
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="bench_live_") as tmp:
        for i in range(args.pairs):
            order = VARIANTS if i % 2 == 0 else VARIANTS[::-1]  # alternating: no variant always first after a pause
            for variant in order:
                rows.append({"round": i, **one_run(args.scenario, variant, args.compose, Path(tmp))})
    medians = {v: statistics.median(r["wall_time_s"] for r in rows if r["variant"] == v) for v in VARIANTS}
    result = {
        "scenario": args.scenario,
        "composed": args.compose,
        "loop_time": "wall_time_s of sappc run --json: the plant's first sample to its last",
        "runs": rows,
        "median_wall_time_s": medians,
        "ratio_to_plain": {v: medians[v] / medians["plain"] for v in VARIANTS},
        "target": "within 10 % of the run without --live (issue 51)",
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count(),
                    "load_average_before": load_before, "load_average_after": os.getloadavg()},
        "date": time.strftime("%Y-%m-%d %H:%M"),
    }
    text = json.dumps(result, indent=1)
    if args.out:
        Path(args.out).write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``sappc replay BAG --live`` on a long bag with a client subscribed to every topic: the server's
peak memory (issue 51: a bag of the 6 h orbit run served in bounded memory).

    .venv/bin/python -m sappc simulate config/scenarios/paper_tracking_orbit.yaml --record /tmp/orbit6h/bag
    .venv/bin/python benchmarks/bench_live_replay.py /tmp/orbit6h/bag > benchmarks/results_speed/live_replay_orbit6h.json

The replay runs at ``--rate 1000000`` (as fast as it can) under ``/usr/bin/time -v`` (its peak
resident set), waits for one subscriber, and a client of the Foxglove WebSocket protocol in this
process subscribes to every advertised channel and counts what it receives until the server
closes (a client slower than the replay loses the oldest queued messages, by design: the count
shows how many it kept up with).  Prints JSON.
"""
import os
import platform
import asyncio
import json
import re
import subprocess
import sys
import time

import websockets
proc = subprocess.Popen(["/usr/bin/time", "-v", sys.executable, "-m", "sappc", "replay", sys.argv[1], "--live", "0", "--rate", "1000000", "--wait-subscribers", "1"],
                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
url = None
lines = []
for line in proc.stdout:
    lines.append(line)
    m = re.search(r"ws://\S+", line)
    if m:
        url = m.group(0); break
counts = {"messages": 0, "topics": set()}
async def watch():
    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"], max_size=None, open_timeout=60) as ws:
        channels = {}
        t0 = time.monotonic()
        while time.monotonic() - t0 < 2.0 or not channels:
            try:
                m = await asyncio.wait_for(ws.recv(), 1.0)
            except asyncio.TimeoutError:
                continue
            if isinstance(m, str) and json.loads(m)["op"] == "advertise":
                channels.update({c["id"]: c for c in json.loads(m)["channels"]})
        subs = dict(enumerate(channels))
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": s, "channelId": c} for s, c in subs.items()]}))
        try:
            while True:
                m = await asyncio.wait_for(ws.recv(), 600)
                if isinstance(m, bytes) and m[0] == 1:
                    counts["messages"] += 1
                    counts["topics"].add(subs[int.from_bytes(m[1:5], "little")])
        except websockets.ConnectionClosed:
            pass
        return len(channels)
t0 = time.monotonic()
n = asyncio.run(watch())
out, err = proc.communicate()
print(json.dumps({"bag": sys.argv[1], "bag_bytes": sum(os.path.getsize(os.path.join(sys.argv[1], f)) for f in os.listdir(sys.argv[1]) if f.endswith(".mcap")),
                  "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "load_average_after": os.getloadavg()},
                  "date": time.strftime("%Y-%m-%d %H:%M"), "channels": n, "client_messages": counts["messages"], "client_topics": len(counts["topics"]), "wall_s": time.monotonic() - t0,
                  "exit": proc.returncode, "stdout": "".join(lines) + out[-500:],
                  "max_rss_kb": [l for l in err.splitlines() if "Maximum resident" in l], "elapsed": [l for l in err.splitlines() if "Elapsed" in l]}, indent=1))

"""What a SIGKILLed recorder loses: data of the last moments before the kill, in seconds.

A publisher sends the nine 100 Hz topics of a lockstep run's load (``state/rate`` messages on nine
channels' worth of traffic: 900 messages/s, each stamped with its publish time) to
``python -m sappc.graph.recorder`` (``mode:=realtime``, a wall-time bag; a lockstep one is
flushed the same way) on an isolated domain; after ``--run-s`` seconds the recorder
is killed with SIGKILL, ``sappc repair`` makes the bag whole, and the bag is read with rosbags.
Loss = publish time of the kill minus the publish time of the last message recovered [s] (the
the documented bound, docs/how-to/bags.md: 1 s).  Prints JSON: every repeat and the median.

    python benchmarks/bench_recorder_kill.py [--repeats 5] [--run-s 5]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RATE_HZ = 100.0
#: Channels' worth of traffic per sample (the nine topics of a lockstep run).
TOPICS_PER_SAMPLE = 9


def one(run_s: float, tmp: Path) -> dict[str, float]:
    import rclpy
    from rclpy.node import Node

    from sappc.graph.launch import claim_domain_id, isolated_environment
    from sappc_msgs_py import contract as c
    from sappc_msgs_py.convert import vector3_msg

    bag_dir = tmp / "bag"
    with claim_domain_id() as domain:
        env = isolated_environment(domain, tmp / "logs")
        os.environ.update(env)
        rec = subprocess.Popen([sys.executable, "-m", "sappc.graph.recorder", "--ros-args", "-p", f"output_dir:={bag_dir}", "-p", "mode:=realtime"],
                               env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)
        context = rclpy.context.Context()
        rclpy.init(context=context, domain_id=domain)
        node = Node("load", context=context)
        pub = node.create_publisher(c.STATE_RATE.msg_class, c.STATE_RATE.name, c.qos_profile())
        deadline = time.monotonic() + 30
        while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
            time.sleep(0.02)
        t0 = time.time()
        k = 0
        while time.time() - t0 < run_s:
            for _ in range(TOPICS_PER_SAMPLE):
                pub.publish(vector3_msg([time.time(), float(k), 0.0], k / RATE_HZ, c.STATE_RATE))
            k += 1
            time.sleep(max(0.0, t0 + k / RATE_HZ - time.time()))
        kill_time = time.time()
        rec.send_signal(signal.SIGKILL)
        rec.wait()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        subprocess.run([str(Path(sys.executable).parent / "fastdds"), "shm", "clean"], capture_output=True, check=False)
    subprocess.run([sys.executable, "-m", "sappc", "repair", str(bag_dir)], capture_output=True, check=True, cwd=ROOT)
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    last = 0.0
    count = 0
    with AnyReader([bag_dir], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            last = max(last, float(msg.vector.x))
            count += 1
    return {"published": k * TOPICS_PER_SAMPLE, "recovered": count, "lost_s": kill_time - last}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--run-s", type=float, default=5.0)
    args = ap.parse_args()
    runs = []
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory() as d:
            runs.append(one(args.run_s, Path(d)))
    print(json.dumps({
        "benchmark": "recorder killed with SIGKILL, then sappc repair",
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()},
        "load_msgs_per_s": RATE_HZ * TOPICS_PER_SAMPLE,
        "runs": runs,
        "lost_s_median": statistics.median(r["lost_s"] for r in runs),
        "lost_s_max": max(r["lost_s"] for r in runs),
        "bound_s": 1.0,
    }, indent=2))


if __name__ == "__main__":
    main()

"""Issue 28, rows 4 and 5: rclpy's own floor for the lockstep loop's message pattern, bare.

    python benchmarks/bench_graph_floor.py [--steps 6001] [--repeats 3] [--domain-id N]

The graph of ``sappc run`` (experiment 1) with every node reduced to its messages: per sample the
"plant" publishes ``/clock``, ``state/attitude``, ``state/rate`` and ``state/tf``; on the clock the
"reference" publishes its four topics and the "injector" the disturbance; the "controller", once
it holds the sample's five inputs, publishes the torque and its diagnostics (a ``Float64MultiArray``
of the project's size); the plant starts the next sample once it holds the sample's torque and
disturbance; a "recorder" takes every message of the 11 topics raw (bytes) and keeps them.  The
same message types, topics, sizes, QoS (reliable; KEEP_ALL for the recorder) and counts (11
messages and 21 deliveries per sample) as the project's graph, and no numerical work, no
checks, no bag: what rclpy and the middleware cost for this pattern.

Two layouts, as ``sappc run``: all nodes in one process on one ``EventsExecutor`` (``--compose``'s)
and one process per node (five, each on its ``EventsExecutor``); each with Python message objects
(``messages``: what the project's nodes publish and take, the recorder aside) and with
serialized messages end to end (``serialized``: every publisher publishes the CDR bytes, its stamp
written into a serialized template, every subscription takes the bytes raw: the floor of the
issue's "serialized messages end to end" direction).  The loop's time is from the
first sample's clock to the last sample's torque; the start (imports, discovery, matching) is
not in it.  Prints one JSON document: per layout, the median over ``--repeats`` of the loop [s],
microseconds per sample and messages per second, and the machine.  ``docs/performance.md`` quotes
the project's loop as a ratio to it.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import paired  # noqa: E402

#: The diagnostics' length: the project's layout (rows of 3 values).
_DIAG_LEN = 30

#: One node of the bare graph (role in argv[1]), or all of them ("all"), spun until the plant's
#: last sample; the plant's process prints the loop's wall time.
_NODE = r"""
import sys, time, json
import rclpy
from rclpy.experimental.events_executor import EventsExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy
from rosgraph_msgs.msg import Clock
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped, TransformStamped, WrenchStamped
from std_msgs.msg import Float64MultiArray
roles, steps, diag_len = sys.argv[1].split(","), int(sys.argv[2]), int(sys.argv[3])
serialized = sys.argv[5] == "serialized"
import struct
from rclpy.serialization import serialize_message
_STAMP = struct.Struct("<iI")  # CDR: 4-byte encapsulation, then the stamp's sec (int32), nanosec (uint32)
_templates = {}
rclpy.init()
qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
keep_all = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
TOPICS = {"/clock": Clock, "state/attitude": QuaternionStamped, "state/rate": Vector3Stamped, "state/tf": TransformStamped,
          "reference/attitude": QuaternionStamped, "reference/rate": Vector3Stamped, "reference/acceleration": Vector3Stamped,
          "reference/tf": TransformStamped, "disturbance/torque": WrenchStamped, "control/torque": WrenchStamped,
          "controller/diagnostics": Float64MultiArray}
nodes, state = [], {"done": False, "t0": None, "t1": None}
def stamped(cls, k):
    if serialized:  # the bytes of the message, the stamp written into a serialized template
        b = _templates.get(cls)
        if b is None:
            b = _templates[cls] = bytearray(serialize_message(cls()))
        b = bytearray(b)
        _STAMP.pack_into(b, 4, *divmod(k * 10_000_000, 1_000_000_000))
        return bytes(b)
    m = cls()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(k * 10_000_000, 1_000_000_000)
    return m
def k_of(m):
    if serialized:
        sec, ns = _STAMP.unpack_from(m, 4)
    else:
        st = m.clock if isinstance(m, Clock) else m.header.stamp
        sec, ns = st.sec, st.nanosec
    return (sec * 1_000_000_000 + ns) // 10_000_000
if "plant" in roles:
    n = rclpy.create_node("plant"); nodes.append(n)
    pubs = {t: n.create_publisher(TOPICS[t], t, qos) for t in ("/clock", "state/attitude", "state/rate", "state/tf")}
    got = {"control/torque": -1, "disturbance/torque": -1}
    def step(k):
        if serialized:
            pubs["/clock"].publish(stamped(Clock, k))
        else:
            c = Clock(); c.clock.sec, c.clock.nanosec = divmod(k * 10_000_000, 1_000_000_000)
            pubs["/clock"].publish(c)
        for t in ("state/attitude", "state/rate", "state/tf"):
            pubs[t].publish(stamped(TOPICS[t], k))
    state["k"] = 0
    def on_back(topic, msg):
        got[topic] = k_of(msg)
        if got["control/torque"] == got["disturbance/torque"] == state["k"]:
            if state["k"] == steps - 1:
                state["t1"], state["done"] = time.perf_counter(), True
            else:
                state["k"] += 1
                step(state["k"])
    for t in got:
        n.create_subscription(WrenchStamped, t, lambda m, t=t: on_back(t, m), qos, raw=serialized)
    state["step"] = step
if "reference" in roles:
    n = rclpy.create_node("reference"); nodes.append(n)
    rp = {t: n.create_publisher(TOPICS[t], t, qos) for t in ("reference/attitude", "reference/rate", "reference/acceleration", "reference/tf")}
    def on_clock_ref(c):
        k = k_of(c)
        for t, p in rp.items():
            p.publish(stamped(TOPICS[t], k))
    n.create_subscription(Clock, "/clock", on_clock_ref, qos, raw=serialized)
if "injector" in roles:
    n = rclpy.create_node("injector"); nodes.append(n)
    dp = n.create_publisher(WrenchStamped, "disturbance/torque", qos)
    n.create_subscription(Clock, "/clock", lambda c: dp.publish(stamped(WrenchStamped, k_of(c))), qos, raw=serialized)
if "controller" in roles:
    n = rclpy.create_node("controller"); nodes.append(n)
    tp = n.create_publisher(WrenchStamped, "control/torque", qos)
    gp = n.create_publisher(Float64MultiArray, "controller/diagnostics", qos)
    have = {}
    diag = serialize_message(Float64MultiArray(data=[0.0] * diag_len))
    def on_input(topic, m):
        k = k_of(m)
        have[topic] = k
        if len(have) == 5 and all(v == k for v in have.values()):
            tp.publish(stamped(WrenchStamped, k))
            if serialized:
                gp.publish(diag)
            else:
                d = Float64MultiArray(); d.data = [float(k)] * diag_len
                gp.publish(d)
    for t in ("state/attitude", "state/rate", "reference/attitude", "reference/rate", "reference/acceleration"):
        n.create_subscription(TOPICS[t], t, lambda m, t=t: on_input(t, m), qos, raw=serialized)
if "recorder" in roles:
    n = rclpy.create_node("recorder"); nodes.append(n)
    kept = []
    for t, cls in TOPICS.items():
        n.create_subscription(cls, t, kept.append, keep_all, raw=True)
ex = EventsExecutor()
for n in nodes:
    ex.add_node(n)
# start once every publication of the graph is matched on both sides (the plant's publishers with
# their subscribers, and its subscriptions with theirs: the graph's 21 deliveries)
expected = {"/clock": 3, "state/attitude": 2, "state/rate": 2, "state/tf": 1}
graph = {"reference/attitude": 2, "reference/rate": 2, "reference/acceleration": 2, "reference/tf": 1, "disturbance/torque": 2,
         "control/torque": 2, "controller/diagnostics": 1}
if "plant" in roles:
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.01)
        if all(pubs[t].get_subscription_count() >= c for t, c in expected.items()) and all(
                n.count_publishers(t) >= 1 and n.count_subscribers(t) >= subs for t, subs in graph.items()):
            break
    else:
        raise SystemExit("the bare graph did not match within 60 s")
    time.sleep(1.0)  # the others' own matches (discovered above; matched on both sides by now)
    for _ in range(50):
        ex.spin_once(timeout_sec=0.01)
    state["t0"] = time.perf_counter()
    state["step"](0)
    while not state["done"]:
        ex.spin_once(timeout_sec=1.0)
    print(json.dumps({"loop_s": state["t1"] - state["t0"]}), flush=True)
else:
    end = time.monotonic() + float(sys.argv[4])
    while time.monotonic() < end:
        ex.spin_once(timeout_sec=0.1)
ex.shutdown()
rclpy.shutdown()
"""

_ROLES = ("plant", "reference", "injector", "controller", "recorder")


def _env(domain: int) -> dict[str, str]:
    return {**os.environ, "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}


def _composed(py: str, steps: int, domain: int, mode: str) -> float:
    out = subprocess.run([py, "-c", _NODE, ",".join(_ROLES), str(steps), str(_DIAG_LEN), "0", mode], env=_env(domain), capture_output=True,
                         text=True, timeout=600)
    if out.returncode != 0:
        raise SystemExit(f"the composed floor failed:\n{out.stderr[-3000:]}")
    return float(json.loads(out.stdout.strip().splitlines()[-1])["loop_s"])


def _processes(py: str, steps: int, domain: int, mode: str) -> float:
    others = [subprocess.Popen([py, "-c", _NODE, role, str(steps), str(_DIAG_LEN), "600", mode], env=_env(domain), stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL) for role in _ROLES[1:]]
    try:
        out = subprocess.run([py, "-c", _NODE, "plant", str(steps), str(_DIAG_LEN), "0", mode], env=_env(domain), capture_output=True, text=True,
                             timeout=600)
        if out.returncode != 0:
            raise SystemExit(f"the five-process floor failed:\n{out.stderr[-3000:]}")
        return float(json.loads(out.stdout.strip().splitlines()[-1])["loop_s"])
    finally:
        for p in others:
            p.terminate()
        for p in others:
            p.wait(timeout=30)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=6001, help="samples (default 6001: experiment 1, 60 s at 100 Hz)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--domain-id", type=int, default=int(os.environ.get("SAPPC_BENCH_DOMAIN", "87")))
    args = parser.parse_args()
    py = paired.python_of(paired.ROOT)
    load_before = os.getloadavg()[0]
    result: dict[str, object] = {"row": "graph_floor_bare_rclpy", "date": time.strftime("%Y-%m-%d"), "machine": paired.machine(),
                                 "steps": args.steps, "messages_per_step": 11, "deliveries_per_step": 21, "repeats": args.repeats}
    for mode in ("messages", "serialized"):
        for name, fn in (("composed", _composed), ("five_processes", _processes)):
            loops = [fn(py, args.steps, args.domain_id, mode) for _ in range(args.repeats)]
            med = statistics.median(loops)
            result[f"{name}_{mode}"] = {"loop_s": {"median": med, "min": min(loops), "max": max(loops), "runs": loops},
                                        "us_per_step": med / args.steps * 1e6, "messages_per_s": 11 * args.steps / med}
    result["load_average_1min"] = {"before": load_before, "after": os.getloadavg()[0]}
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

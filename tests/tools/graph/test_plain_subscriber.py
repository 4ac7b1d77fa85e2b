"""A plain rclpy subscriber reads every topic of a run (issue 48: the nodes publish CDR bytes).

The nodes publish the bytes of :mod:`sappc_msgs_py.wire` and subscribe ``raw=True``; what they send
must still be the standard messages any ROS 2 tool reads.  A plain rclpy node, in a process of its
own (message objects of ``geometry_msgs``, ``std_msgs`` and ``rosgraph_msgs``, no ``raw=True``,
the contract's QoS), subscribes to the eleven topics of a lockstep ``sappc run --compose`` of
experiment 1 cut short to 3 s, on the run's domain; it decodes each message with the object
decoders of :mod:`sappc_msgs_py.convert` and writes what it got to a JSON file.  Every topic
delivered every sample the run published, with the contract's frames and labels, and the values
equal what the bag holds, bit for bit.

Start-up without timing luck: every publisher of a run waits for its ``expected_subscribers``
before its first message (the plant before its first sample, the reference before publishing
ahead), and ``sappc run`` has no option or environment variable that adds a subscriber of the
user's to those counts.  So the test runs the ``sappc`` command (``sappc.__main__.main``) with
:func:`sappc.graph.launch.node_parameters` wrapped to count one more subscriber of each of the
eleven topics (:data:`WRAPPED_SAPPC`): the run waits for the plain subscriber however late it
joins, and no count of the run's own nodes is met by it instead (the plant's ``/clock`` count,
which waits for the recorder, stays one more than the subscribers the run has without it).
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from conftest import ROOT, SCENARIOS, cut_short
from shm_watch import ShmWatch

pytestmark = pytest.mark.slow

#: The run's length [s] and its samples (one at t = 0 and every 10 ms to the end, both included).
DURATION_S = 3.0
SAMPLES = 301
#: The topics of a lockstep run of experiment 1, as the plain subscriber names them (resolved in the root namespace).
TOPICS = ["/clock", "/state/attitude", "/state/rate", "/state/tf", "/reference/attitude", "/reference/rate", "/reference/acceleration",
          "/reference/tf", "/disturbance/torque", "/control/torque", "/controller/diagnostics"]
#: How long a step of the test may take at most [s] (the run takes about 5 s here; the limits only end a hung run).
TIMEOUT_S = 300

#: ``sappc`` with one more expected subscriber of each topic named in ``argv[1]`` (comma separated)
#: for every node of the run; ``argv[2:]``: the command's arguments.
WRAPPED_SAPPC = """
import sys

import sappc.graph.launch as launch
from sappc.__main__ import main
from sappc_msgs_py.runtime import parse_expected

extra = set(sys.argv[1].split(","))
node_parameters = launch.node_parameters


def with_the_plain_subscriber(*args, **kwargs):
    params = node_parameters(*args, **kwargs)
    for node in params.values():
        p = node["ros__parameters"]
        if "expected_subscribers" in p:
            p["expected_subscribers"] = [f"{t}={n + (t in extra)}" for t, n in parse_expected(p["expected_subscribers"]).items()]
    return params


launch.node_parameters = with_the_plain_subscriber
sys.exit(main(sys.argv[2:]))
"""

#: The plain subscriber: ``argv[1]`` the JSON file it writes, ``argv[2]`` the file whose existence
#: tells it to stop (it then takes what is still queued, until nothing came for 1 s).
PLAIN_SUBSCRIBER = '''
import json
import math
import sys
import time
from pathlib import Path

import rclpy
from geometry_msgs.msg import QuaternionStamped, TransformStamped, Vector3Stamped, WrenchStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray

from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import diagnostics_from_msg, quaternion_from_msg, stamp_to_ns, torque_from_msg, vector3_from_msg

out_path, stop_path = Path(sys.argv[1]), Path(sys.argv[2])
TYPES = {"/clock": Clock, "/state/attitude": QuaternionStamped, "/state/rate": Vector3Stamped, "/state/tf": TransformStamped,
         "/reference/attitude": QuaternionStamped, "/reference/rate": Vector3Stamped, "/reference/acceleration": Vector3Stamped,
         "/reference/tf": TransformStamped, "/disturbance/torque": WrenchStamped, "/control/torque": WrenchStamped,
         "/controller/diagnostics": Float64MultiArray}
CONTRACT = {"/" + t.name.lstrip("/"): t for t in c.TOPICS}
got = {name: [] for name in TYPES}
errors = []


def floats(values):
    return [float(v) for v in values]


def entry(name, msg):
    """What the message holds, read from the object, and its value through convert.py's object decoder."""
    topic = CONTRACT[name]
    if isinstance(msg, Clock):
        return {"stamp": stamp_to_ns(msg.clock)}
    if isinstance(msg, Float64MultiArray):
        rows = diagnostics_from_msg(msg)
        return {"labels": [d.label for d in msg.layout.dim], "sizes": [d.size for d in msg.layout.dim],
                "strides": [d.stride for d in msg.layout.dim], "data_offset": msg.layout.data_offset, "values": floats(msg.data),
                "decoded": [x for label in c.DIAGNOSTICS_LAYOUT for x in floats(rows[label])]}
    e = {"stamp": stamp_to_ns(msg.header.stamp), "frame": msg.header.frame_id}
    if isinstance(msg, QuaternionStamped):
        q = msg.quaternion
        e["values"], e["decoded"] = [q.x, q.y, q.z, q.w], floats(quaternion_from_msg(msg, topic))
    elif isinstance(msg, Vector3Stamped):
        v = msg.vector
        e["values"], e["decoded"] = [v.x, v.y, v.z], floats(vector3_from_msg(msg, topic))
    elif isinstance(msg, WrenchStamped):
        f, t = msg.wrench.force, msg.wrench.torque
        e["force"], e["values"], e["decoded"] = [f.x, f.y, f.z], [t.x, t.y, t.z], floats(torque_from_msg(msg, topic))
    else:  # TransformStamped
        tr, r = msg.transform.translation, msg.transform.rotation
        e["child"], e["translation"], e["values"] = msg.child_frame_id, [tr.x, tr.y, tr.z], [r.x, r.y, r.z, r.w]
    return e


def callback(name):
    def take(msg):
        try:
            got[name].append(entry(name, msg))
        except Exception as exc:  # noqa: BLE001 (every failure is reported, as the test's)
            errors.append(f"{name}: {type(exc).__name__}: {exc}")
    return take


rclpy.init()
node = Node("plain_subscriber")
qos = c.qos_profile()
subs = [node.create_subscription(TYPES[name], name, callback(name), qos) for name in TYPES]
executor = SingleThreadedExecutor()
executor.add_node(node)
print("subscribed", flush=True)
while not stop_path.exists():
    executor.spin_once(timeout_sec=0.05)
count, quiet_since = -1, time.monotonic()
while time.monotonic() - quiet_since < 1.0:
    executor.spin_once(timeout_sec=0.05)
    n = sum(map(len, got.values()))
    if n != count:
        count, quiet_since = n, time.monotonic()
out_path.write_text(json.dumps({"messages": got, "errors": errors}))
node.destroy_node()
rclpy.try_shutdown()
'''

_DOMAIN_LINE = re.compile(r", domain (\d+) \(")


def _wait_for_domain(log: Path, run: subprocess.Popen[bytes], deadline: float) -> int:
    """The domain ``sappc run`` claimed, from its start line (it starts the nodes before it says so)."""
    while True:
        m = _DOMAIN_LINE.search(log.read_text())
        if m is not None:
            return int(m.group(1))
        assert run.poll() is None, f"sappc run ended before it started its nodes:\n{log.read_text()}"
        assert time.monotonic() < deadline, f"sappc run never said its domain:\n{log.read_text()}"
        time.sleep(0.05)


@pytest.fixture(scope="module")
def plain_run(tmp_path_factory):  # type: ignore[no-untyped-def]
    """The 3 s lockstep composed run and the plain subscriber beside it: (what the subscriber got,
    the run's JSON summary, the run directory)."""
    from sappc.graph.launch import isolated_environment

    tmp = tmp_path_factory.mktemp("plain")
    scenario = tmp / "short.yaml"
    scenario.write_text(yaml.safe_dump(cut_short(yaml.safe_load((SCENARIOS / "paper_tracking.yaml").read_text()), DURATION_S)))
    subscriber = tmp / "plain_subscriber.py"
    subscriber.write_text(PLAIN_SUBSCRIBER)
    out, summary, got, stop = tmp / "run", tmp / "run.json", tmp / "got.json", tmp / "stop"
    run_log, sub_log = tmp / "run.log", tmp / "subscriber.log"
    deadline = time.monotonic() + TIMEOUT_S
    with ShmWatch() as watch, run_log.open("wb") as run_out, sub_log.open("wb") as sub_out:
        run = subprocess.Popen([sys.executable, "-c", WRAPPED_SAPPC, ",".join(t.lstrip("/") if t != "/clock" else t for t in TOPICS),
                                "run", str(scenario), "--compose", "--out", str(out), "--json", str(summary)],
                               cwd=ROOT, stdout=run_out, stderr=subprocess.STDOUT)
        watch.add(run.pid)
        sub: subprocess.Popen[bytes] | None = None
        try:
            domain = _wait_for_domain(run_log, run, deadline)
            sub = subprocess.Popen([sys.executable, str(subscriber), str(got), str(stop)], cwd=ROOT, stdout=sub_out,
                                   stderr=subprocess.STDOUT, env=isolated_environment(domain, tmp / "subscriber_ros_log"))
            watch.add(sub.pid)
            while run.poll() is None:  # the run waits for the subscriber: one that failed would leave it waiting
                assert sub.poll() is None, f"the plain subscriber exited during the run:\n{sub_log.read_text()}"
                assert time.monotonic() < deadline, f"the run did not end within {TIMEOUT_S} s:\n{run_log.read_text()}"
                time.sleep(0.1)
            stop.touch()
            sub.wait(timeout=60)
        finally:
            for p in (run, sub):
                if p is not None and p.poll() is None:
                    p.send_signal(signal.SIGINT)
                    try:
                        p.wait(timeout=60)
                    except subprocess.TimeoutExpired:
                        p.kill()
                        p.wait()
    assert run.returncode == 0, run_log.read_text()
    assert sub.returncode == 0, sub_log.read_text()
    watch.assert_clean()  # no process of the run or the subscriber alive, none of their shared memory left
    return json.loads(got.read_text()), json.loads(summary.read_text()), out


def test_every_topic_delivered_every_sample_to_a_plain_subscriber(plain_run) -> None:  # type: ignore[no-untyped-def]
    """Each of the eleven topics reached a plain rclpy subscriber (message objects, the contract's QoS) with
    every sample the run published, in stamp order, and convert.py's object decoders took every one."""
    got, summary, _ = plain_run
    assert got["errors"] == []
    messages = got["messages"]
    grid = [k * 10_000_000 for k in range(SAMPLES)]
    for topic in TOPICS:
        assert summary["published"][topic] == SAMPLES, (topic, summary["published"])
        assert len(messages[topic]) == SAMPLES, (topic, len(messages[topic]))
        if topic != "/controller/diagnostics":
            assert [m["stamp"] for m in messages[topic]] == grid, topic
        for m in messages[topic]:
            if "decoded" in m:  # the object decoder's value is the message's own
                np.testing.assert_array_equal(m["decoded"], m["values"], err_msg=topic)


def test_the_plain_subscriber_sees_the_contracts_frames_labels_and_transforms(plain_run) -> None:  # type: ignore[no-untyped-def]
    """Frame ids, the transforms' child frames, zero translation and force, the transforms' rotation the
    attitude's, and the diagnostics' labelled layout, as a standard message carries them."""
    from sappc_msgs_py.contract import DIAGNOSTICS_LAYOUT, TOPICS as CONTRACT_TOPICS
    from sappc_msgs_py.convert import seconds_to_ns

    messages = plain_run[0]["messages"]
    contract = {"/" + t.name.lstrip("/"): t for t in CONTRACT_TOPICS}
    for topic in TOPICS:
        if topic in ("/clock", "/controller/diagnostics"):
            continue
        assert {m["frame"] for m in messages[topic]} == {contract[topic].frame_id}, topic
    for tf, attitude, child in (("/state/tf", "/state/attitude", "body"), ("/reference/tf", "/reference/attitude", "reference")):
        assert {m["child"] for m in messages[tf]} == {child}
        assert all(m["translation"] == [0.0, 0.0, 0.0] for m in messages[tf])
        assert [m["values"] for m in messages[tf]] == [m["values"] for m in messages[attitude]]  # the rotation is the attitude
    for wrench in ("/control/torque", "/disturbance/torque"):
        assert all(m["force"] == [0.0, 0.0, 0.0] for m in messages[wrench])
    n = len(DIAGNOSTICS_LAYOUT)
    for k, m in enumerate(messages["/controller/diagnostics"]):
        assert m["labels"] == [",".join(DIAGNOSTICS_LAYOUT), "axis"] and m["sizes"] == [n, 3] and m["strides"] == [3 * n, 3]
        assert m["data_offset"] == 0 and len(m["values"]) == 3 * n
        assert {seconds_to_ns(t) for t in m["values"][:3]} == {k * 10_000_000}  # time_s: the sample's


def test_what_the_plain_subscriber_got_is_what_the_bag_holds(plain_run) -> None:  # type: ignore[no-untyped-def]
    """The values a plain subscriber read from the message objects equal, bit for bit, those the project's
    bag reader decodes from the recorded bytes, sample by sample, on every topic."""
    from sappc.bag.read import read_bag

    messages, _, out = plain_run[0]["messages"], plain_run[1], plain_run[2]
    bag = read_bag(out / "bag")
    assert set(bag.series) == set(TOPICS)
    for topic in TOPICS:
        series = bag.series[topic]
        assert series.stamps_ns.tolist() == [k * 10_000_000 for k in range(SAMPLES)], topic
        if topic == "/clock":
            assert [m["stamp"] for m in messages[topic]] == series.stamps_ns.tolist()
            continue
        got = np.array([m["values"] for m in messages[topic]], dtype=np.float64)
        assert got.shape == series.values.shape, (topic, got.shape, series.values.shape)
        assert got.tobytes() == np.ascontiguousarray(series.values, dtype=np.float64).tobytes(), topic  # bit for bit (NaN included)

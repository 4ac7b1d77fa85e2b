"""Issues 28 and 48: rclpy's own floor for the lockstep loop's message pattern, bare.

    python benchmarks/bench_graph_floor.py [--scenario paper_tracking] [--steps 6001] [--repeats 3]
                                           [--from-run DIR] [--probe-s 3] [--ahead 1] [--modes messages,serialized,work]
                                           [--domain-id N]

The graph of ``sappc run SCENARIO`` (lockstep) with every node reduced to its messages, and no
numerical work, no checks, no bag: what rclpy and the middleware cost for this pattern.

The bare graph is derived from a real run of the scenario, not written by hand: ``--from-run DIR``
(a directory ``sappc run SCENARIO --compose --out DIR`` wrote), or by default a probe run of the
scenario cut to ``--probe-s`` seconds (a scenario file with ``extends:`` and ``duration_s``) that
this script starts first.  From that run directory:

- the nodes: those ``sappc run`` started (``composition.json``), each with its remaps;
- what each node publishes, and to how many subscribers each topic goes: ``params.yaml``, each
  node's ``expected_subscribers`` (what :func:`sappc.graph.launch.node_parameters` made of the
  scenario), and the recorder's ``topics``; cross-checked against ``counts/<node>.json``, the topics
  each node actually published;
- how often: every topic's messages in the run's bag, by stamp: every sample, or every Nth
  (``sensors/star_tracker`` at the tracker's rate, the estimator's health on ``diagnostics`` once a
  second); the schedule must reproduce the run's count of each topic exactly;
- the message types and the real serialized messages: the last message of each topic in the bag
  (its CDR bytes, what the project's nodes sent), into which each publish writes its stamp (the
  header's, ``/clock``'s, or ``data[0]`` of a ``Float64MultiArray``, the contract's time label);
- what each node subscribes to: the node modules' ``create_subscription`` calls, as a table here
  (:data:`_ROLE_INPUTS`), remapped as the run remapped them; the number of subscriptions this gives
  each topic (the recorder's included) must be at least what its publisher waits for
  (``expected_subscribers``), else the script stops: the self-check of the topology (a subscriber
  its publisher does not wait for is kept and listed in the JSON: paper_tracking_orbit's momentum
  node on ``estimate/attitude``, which the estimator's ``expected_subscribers`` leaves out);
- the QoS: :func:`sappc_msgs_py.contract.qos_profile` (RELIABLE, VOLATILE, KEEP_LAST 10,000), and
  the recorder's RELIABLE, VOLATILE, KEEP_ALL.

The lockstep dataflow, as the nodes run it: the "plant" publishes ``/clock`` and its per-sample
topics of sample ``k`` (in its order), waits for every input of ``k`` it takes (the torque, or the
momentum node's wheel torque; the disturbance; the rods' dipoles where the scenario has them),
publishes what it publishes once the command is applied (``joint_states``), then starts ``k + 1``;
the "reference" and the "injector" publish, on each ``/clock`` tick ``k``, every sample up to ``k +
--ahead`` not yet published (``--ahead 1``, the nodes' ``GridCursor``: one sample ahead, off the
loop's critical path; ``--ahead 0``: sample ``k`` on tick ``k``, the pattern of this script before
issue 48); the "estimator" publishes its outputs of ``k`` once it holds the gyro and the tracker's
epoch of ``k`` and, at the samples where the tracker makes one, the tracker sample; the
"controller" once it holds its five inputs of ``k``; the "momentum" node once it holds its five;
the controller and the estimator also take ``/clock`` (their lockstep checks); a "recorder" takes
every message of every topic raw (bytes) and keeps them.

Two layouts, as ``sappc run``: all nodes in one process on one ``EventsExecutor`` (``--compose``'s)
and one process per node (each on its ``EventsExecutor``; five for paper_tracking); each with
Python message objects (``messages``: every publisher fills one message object, re-stamped, and
every subscription but the recorder's takes message objects) and with serialized messages end to
end (``serialized``: every publisher publishes the CDR bytes, its stamp written into the real
message's bytes, every subscription takes the bytes raw: the floor of issue 48's "serialized
messages end to end" direction).  The loop's time is from the first sample's clock to the last
sample's inputs at the plant; the start (imports, discovery, matching) is not in it.  Prints one
JSON document: the scenario, the bare graph (per topic: type, bytes, publisher, subscribers,
period in samples), messages and deliveries per sample, the self-check (the schedule against the
probe run's counts, and the messages each bare run published and delivered against the schedule),
and per layout and mode the median over ``--repeats`` of the loop [s], microseconds per sample and
messages per second; and the machine.  ``docs/performance.md`` quotes the project's loop as a ratio
to it.

What changed with issue 48 (``--scenario``), for paper_tracking's figures against the earlier ones
(``results_speed``, docs/performance.md of 2026-11-26): the graph is the run's, so the controller's
``/clock`` subscription is in it (21 deliveries a sample, as the earlier docstring said; its
hand-written graph had 20), the reference and the injector publish one sample ahead as the nodes
do (``--ahead 0``: on the tick, as before), the messages are the real ones (the diagnostics 468
bytes with their labels, not 256) re-stamped in one object per publisher rather than built per
publish, the QoS is the contract's (depth 10,000, not 10), the domain is claimed, and the nodes
run with the project's Fast DDS profile.

A third mode, ``work``, is the floor of Python nodes that do this run's unavoidable work and
nothing else: ``serialized``, plus, with the project's own code, every subscription but the
recorder's unpacks its message's values against the topic's layout (``sappc_msgs_py.wire``'s
``Codec.values``), every publication is encoded from its values (``Codec.encode``, where the topic
has a one-pack layout), the controller steps the run's control law once a sample on the inputs it
decoded (``controller_from_parameters_file`` of the run's ``params.yaml``), the plant steps the
rigid body once a sample into its buffers (``RigidBody.propagate_into``), and the recorder hands
each message to a writer thread that builds the MCAP chunks (``sappc.bag.mcap_write``) a pass at a
time, as the project's recorder does.  No input checks, no pairing beyond counting, no watchdog,
no diagnostics beyond the bytes: what any Python implementation of these nodes pays at least
(the estimator's and the momentum node's own numerical work is not in it, so for the flight
scenario it is lower still than that).  The JSON counts the work done (law steps, plant steps,
messages decoded and written).

Each process spins its ``EventsExecutor`` in C++ (``spin_until_future_complete`` on a future the
plant's last sample completes), as the project's nodes do (``sappc_msgs_py.runtime.run_nodes``).
Until 2026-12-06 it spun in a Python ``spin_once`` loop, which costs a few microseconds a message
more: the floors measured so were not rclpy's (composed ``paper_tracking`` 0.90 s against 0.63 s
spun in C++, five processes 3.18 s against 2.65 s, the same call, machine B), and the ratios
quoted against them were too low by that much (docs/performance.md).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import paired  # noqa: E402
from sappc.graph.launch import claim_domain_id  # noqa: E402  (the parent claims its domain as sappc run does)

#: What each node subscribes to, from the node modules' ``create_subscription`` calls (names before
#: the run's remaps), and how it uses it: ``gates``: the inputs of a sample the node waits for before
#: it publishes that sample (the plant: before it starts the next); ``scheduled``: an input it waits
#: for only at the samples where that topic is published (the estimator's tracker sample, when the
#: epoch names a new one); ``listens``: taken, not waited for (the lockstep ``/clock`` checks);
#: ``trigger``: the topic whose sample ``k`` makes the node publish through ``k + ahead``.
#: spacecraft_sim/plant_node.py (``use_disturbance_topic``, ``use_dipole_topic`` per its parameters),
#: sappc_controller/node.py, sappc_estimator/node.py, sappc_momentum/node.py (``INPUTS``),
#: spacecraft_sim/reference.py, spacecraft_sim/disturbance.py (lockstep, no fault relay).
_ROLE_INPUTS: dict[str, dict[str, list[str]]] = {
    "plant": {"gates": ["/control/torque"]},  # + disturbance/torque, control/dipole by parameter (_topology)
    "controller": {"gates": ["/state/attitude", "/state/rate", "/reference/attitude", "/reference/rate", "/reference/acceleration"],
                   "listens": ["/clock"]},
    "estimator": {"gates": ["/sensors/gyro", "/state/attitude_epoch"], "scheduled": ["/sensors/star_tracker"], "listens": ["/clock"]},
    "momentum": {"gates": ["/state/wheel_speed", "/state/magnetic_field", "/state/attitude", "/state/rate", "/control/torque"]},
    "reference": {"trigger": ["/clock"]},
    "injector": {"trigger": ["/clock"]},
}
#: The plant's publication order within a sample (plant_node.py: _publish_sample, _publish_state,
#: _publish_orbit); ``joint_states`` goes out once the sample's command is applied (_wheel_command).
_PLANT_ORDER = ("/clock", "/state/attitude", "/state/rate", "/sensors/star_tracker", "/sensors/gyro", "/state/attitude_epoch",
                "/truth/attitude", "/truth/rate", "/truth/gyro_bias", "/state/tf", "/state/magnetic_field", "/truth/magnetic_field",
                "/state/wheel_speed")
_PLANT_AFTER_INPUTS = ("/joint_states",)
#: The estimator's publication order (sappc_msgs_py.contract.ESTIMATOR_TOPICS).
_ESTIMATOR_ORDER = ("/estimate/attitude", "/estimate/rate", "/estimator/gyro_bias", "/estimator/attitude_sigma", "/estimator/bias_sigma",
                    "/estimator/covariance", "/estimator/diagnostics", "/diagnostics")

_NUMBERS = ("zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten")

#: One node of the bare graph or several (roles in argv[2]), spun until the plant's last sample
#: (the plant's process prints the loop's wall time) or SIGTERM; each process writes what it
#: published and took per topic to argv[4].
_NODE = r"""
import importlib, json, signal, struct, sys, time
import rclpy
from rclpy.experimental.events_executor import EventsExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy, DurabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
spec = json.load(open(sys.argv[1]))
roles, mode, counts_path = sys.argv[2].split(","), sys.argv[3], sys.argv[4]
serialized, work = mode in ("serialized", "work"), mode == "work"
steps, dt_ns, ahead = spec["steps"], spec["dt_ns"], spec["ahead"]
dt_s, half = dt_ns / 1e9, dt_ns // 2
stop = []
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)  # SIGTERM ends the spin below, which then writes the counts
signal.signal(signal.SIGTERM, lambda *a: stop.append(1))
def qos(q):
    return QoSProfile(reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE,
                      history=HistoryPolicy.KEEP_ALL if q["history"] == "keep_all" else HistoryPolicy.KEEP_LAST, depth=q["depth"])
QOS, REC_QOS = qos(spec["qos"]), qos(spec["recorder_qos"])
T = {}
for name, t in spec["topics"].items():
    pkg, _, cls = t["type"].split("/")
    T[name] = dict(t, cls=getattr(importlib.import_module(pkg + ".msg"), cls), raw=bytes.fromhex(t["raw_hex"]))
_STAMP, _F64 = struct.Struct("<iI"), struct.Struct("<d")
published, received, all_pubs = {}, {}, []
if work:  # the nodes' unavoidable work (module docstring): the project's codecs, law, plant and bag writer
    import queue, tempfile, threading
    import numpy as np
    from sappc_msgs_py import wire
    from sappc_msgs_py.contract import CLOCK, TOPICS
    from sappc_msgs_py.convert import cdr_stamp_ns
    CODECS = {}
    for t in TOPICS:
        if t is CLOCK:
            continue  # a node reads /clock's stamp (sample_of's k_of does): that is its decode
        try:
            CODECS["/" + t.name.lstrip("/")] = wire.codec(t)
        except ValueError:
            pass
    LATEST = {}  # topic -> the last value a work subscription decoded
DONE = {"law_steps": 0, "plant_steps": 0, "messages_written": 0, "decoded": 0}  # work: what was done, in the counts file
def decoder(name):
    # work: what a node does first with a message of the topic: its values unpacked and checked against the layout
    c = CODECS.get(name) if work else None
    if c is None:
        return None
    def decode(m, c=c, name=name):
        v = c.values(m)
        LATEST[name] = np.array(v) if v is not None else None
        DONE["decoded"] += v is not None
    return decode
def publisher(node, name):
    # publish(k): the topic's real message, stamped with sample k (bytes, or one message object re-stamped)
    t = T[name]
    p = node.create_publisher(t["cls"], name, QOS)
    all_pubs.append(p)
    kind, off = t["slot"]
    cnt = published.setdefault(name, [0])
    c = CODECS.get(name) if work else None
    if c is not None and c._whole is not None:  # work: encoded from its values by the project's codec
        values = list(c.values(t["raw"]))
        if kind == "f64":  # data[0], the time label (the controller's diagnostics)
            def pub(k, values=values):
                values[0] = k * dt_s; p.publish(c.encode(None, values)); cnt[0] += 1
        else:
            def pub(k, values=values):
                p.publish(c.encode(k * dt_ns, values)); cnt[0] += 1
        return pub
    if serialized:
        buf = bytearray(t["raw"])
        if kind == "f64":
            def pub(k, buf=buf, pack=_F64.pack_into):
                pack(buf, off, k * dt_s); p.publish(bytes(buf)); cnt[0] += 1
        else:
            def pub(k, buf=buf, pack=_STAMP.pack_into):
                pack(buf, off, *divmod(k * dt_ns, 1_000_000_000)); p.publish(bytes(buf)); cnt[0] += 1
        return pub
    msg = deserialize_message(t["raw"], t["cls"])
    if kind == "f64":
        data = msg.data
        def pub(k):
            data[0] = k * dt_s; p.publish(msg); cnt[0] += 1
    else:
        st = msg.clock if kind == "clock" else msg.header.stamp
        def pub(k):
            st.sec, st.nanosec = divmod(k * dt_ns, 1_000_000_000); p.publish(msg); cnt[0] += 1
    return pub
def sample_of(name):
    # k of a message of the topic (bytes or object)
    kind, off = T[name]["slot"]
    if serialized:
        if kind == "f64":
            return lambda m: round(_F64.unpack_from(m, off)[0] / dt_s)
        def k_of(m):
            sec, ns = _STAMP.unpack_from(m, off)
            return (sec * 1_000_000_000 + ns + half) // dt_ns
        return k_of
    if kind == "f64":
        return lambda m: round(m.data[0] / dt_s)
    if kind == "clock":
        return lambda m: (m.clock.sec * 1_000_000_000 + m.clock.nanosec + half) // dt_ns
    return lambda m: (m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec + half) // dt_ns
def subscribe(node, role, name, callback, q=QOS, raw=None):
    cnt = received.setdefault(role, {}).setdefault(name, [0])
    decode = decoder(name) if role != "recorder" else None
    def on(m):
        cnt[0] += 1
        callback(m)
    if decode is not None:
        def on(m, decode=decode):
            cnt[0] += 1
            decode(m)
            callback(m)
    return node.create_subscription(T[name]["cls"], name, on, q, raw=serialized if raw is None else raw)
def outputs(node, names):
    return [(publisher(node, n), T[n]["period"]) for n in names]
from rclpy.task import Future
finished = Future()  # completed by the plant's last sample: the loop spins in C++ until then (as run_nodes does)
nodes, state = [], {"done": False, "t0": None, "t1": None, "k": 0, "progress": time.monotonic()}
plant_pubs, plant_subs = {}, []
for role in roles:
    r = spec["roles"][role]
    n = rclpy.create_node(role); nodes.append(n)
    for name in r.get("listens", []):
        subscribe(n, role, name, sample_of(name))
    if r["kind"] == "recorder":
        take = [].append
        if work:  # the project's recorder's work: a hand-over queue, a writer thread building MCAP chunks a pass at a time
            from sappc.bag.mcap_write import ChunkBuilder, McapWriter
            handover = queue.SimpleQueue()
            bag = tempfile.NamedTemporaryFile(prefix="floor-", suffix=".mcap")
            mcap = McapWriter(bag, "bench_graph_floor")
            schema = mcap.schema("std_msgs/msg/Empty", "ros2msg", b"")
            chan = {nm: mcap.channel(nm, "cdr", schema, {}) for nm in r["subscribes"]}
            types = {nm: T[nm]["type"] for nm in r["subscribes"]}
            chunks, seqs = ChunkBuilder(mcap, 256 * 1024), {nm: 0 for nm in r["subscribes"]}
            def write_loop():
                while True:
                    batch = [handover.get()]
                    try:
                        while batch[-1] is not None:
                            batch.append(handover.get_nowait())
                    except queue.Empty:
                        pass
                    records = []
                    for item in batch:
                        if item is None:
                            chunks.add_messages(records)
                            chunks.flush()
                            DONE["messages_written"] += len(records)
                            return
                        nm, data = item
                        log_ns = cdr_stamp_ns(types[nm], data)
                        seqs[nm] += 1
                        records.append((chan[nm], seqs[nm], log_ns, log_ns, data))
                    chunks.add_messages(records)
                    DONE["messages_written"] += len(records)
                    time.sleep(0.02)
            writer = threading.Thread(target=write_loop, daemon=True)
            writer.start()
        for name in r["subscribes"]:
            if work:
                take = lambda m, name=name: handover.put((name, m))
            subscribe(n, role, name, take, REC_QOS, raw=True)
    elif r["kind"] == "plant":
        per_sample, after = outputs(n, r["outputs"]), outputs(n, r["after"])
        for name, (pub, _) in zip(r["outputs"], per_sample):
            plant_pubs[name] = pub
        ngates, pending = len(r["gates"]), {}
        body = None
        if work:  # the project's rigid body, stepped once a sample into its buffers (as the plant node does)
            from spacecraft_sim.core.dynamics import RigidBody
            pp = spec["plant"]
            body = RigidBody(np.array(pp["inertia_kg_m2"], dtype=np.float64).reshape(3, 3))
            xs = [np.ascontiguousarray([[0.0, 0.0, 0.0, 1.0, 0.001, 0.0, 0.0]]), np.zeros((1, 7))]
            u_B = np.zeros((1, 3))
        def step(k, per_sample=per_sample):
            if body is not None and k:
                np.add(LATEST.get(r["gates"][0], np.zeros(3)), LATEST.get(r["gates"][-1], np.zeros(3)), out=u_B[0])
                body.propagate_into(xs[0], u_B, dt_s, spec["plant"]["rk4_substeps"], xs[1])
                xs.reverse()
                DONE["plant_steps"] += 1
            for pub, period in per_sample:
                if k % period == 0:
                    pub(k)
        def on_gate(m, k_of, after=after, ngates=ngates, pending=pending, step=step):
            k = k_of(m)
            got = pending.get(k, 0) + 1
            if got < ngates:
                pending[k] = got
                return
            pending.pop(k, None)
            for pub, period in after:
                if k % period == 0:
                    pub(k)
            state["progress"] = time.monotonic()
            if k >= steps - 1:
                state["t1"], state["done"] = time.perf_counter(), True
                finished.set_result(True)
            else:
                state["k"] = k + 1
                step(k + 1)
        for name in r["gates"]:
            plant_subs.append(subscribe(n, role, name, lambda m, k_of=sample_of(name), f=on_gate: f(m, k_of)))
        state["step"] = step
    elif r["kind"] == "ahead":
        outs, cursor = outputs(n, r["outputs"]), [0]
        def on_tick(m, k_of, outs=outs, cursor=cursor):
            end = min(k_of(m) + ahead, steps - 1)
            for j in range(cursor[0], end + 1):
                for pub, period in outs:
                    if j % period == 0:
                        pub(j)
            cursor[0] = max(cursor[0], end + 1)
        for name in r["trigger"]:
            subscribe(n, role, name, lambda m, k_of=sample_of(name), f=on_tick: f(m, k_of))
    else:  # gated: publishes sample k once it holds every input of k
        outs, pending = outputs(n, r["outputs"]), {}
        base, sched = len(r["gates"]), [T[s]["period"] for s in r["scheduled"]]
        law = None
        if work and role == "controller":  # the project's law, stepped once a sample on the inputs decoded
            from sappc_controller.params import CONTROLLER_CLASSES, controller_from_parameters_file
            kind, config, _ = controller_from_parameters_file(spec["params_yaml"])
            law = CONTROLLER_CLASSES[kind](config)
            law_inputs = r["gates"]
        def on_input(m, k_of, outs=outs, pending=pending, base=base, sched=sched, law=law):
            k = k_of(m)
            got = pending.get(k, 0) + 1
            if got < base + sum(1 for p in sched if k % p == 0):
                pending[k] = got
                return
            pending.pop(k, None)
            if law is not None:
                law.step(k * dt_s, dt_s, *(LATEST[t] for t in law_inputs))
                DONE["law_steps"] += 1
            for pub, period in outs:
                if k % period == 0:
                    pub(k)
        for name in r["gates"] + r["scheduled"]:
            subscribe(n, role, name, lambda m, k_of=sample_of(name), f=on_input: f(m, k_of))
ex = EventsExecutor()
for n in nodes:
    ex.add_node(n)
scheduled = {t: len(range(0, steps, v["period"])) for t, v in spec["topics"].items()}
def complete():
    # every subscription of this process has taken every message the schedule sends it
    return all(c[0] >= scheduled[t] for d in received.values() for t, c in d.items())
def write_counts(done):
    with open(counts_path + ".tmp", "w") as f:
        json.dump({"complete": done, "work": DONE, "published": {t: c[0] for t, c in published.items()},
                   "received": {r: {t: c[0] for t, c in d.items()} for r, d in received.items()}}, f)
    import os; os.replace(counts_path + ".tmp", counts_path)
def finish():
    # what this process published is acknowledged by every subscriber before it goes
    from rclpy.duration import Duration
    for p in all_pubs:
        p.wait_for_all_acked(Duration(seconds=10))
    write_counts(complete())
if "plant" in roles:
    # start once every publication of the graph is matched: the plant's publishers with their
    # subscribers and its subscriptions with their publishers, and every other topic with its
    # publisher and its subscribers on the graph (discovered), then a second for their own matches
    pn = nodes[roles.index("plant")]
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.01)
        if all(pn.count_publishers(t) >= 1 and pn.count_subscribers(t) >= c for t, c in spec["subscribers"].items()) \
                and all(s.get_publisher_count() >= 1 for s in plant_subs):
            break
    else:
        missing = {t: (pn.count_publishers(t), pn.count_subscribers(t), c) for t, c in spec["subscribers"].items()
                   if not (pn.count_publishers(t) >= 1 and pn.count_subscribers(t) >= c)}
        raise SystemExit(f"the bare graph did not match within 60 s: (publishers, subscribers, expected) {missing}")
    time.sleep(1.0)
    for _ in range(50):
        ex.spin_once(timeout_sec=0.01)
    state["t0"] = time.perf_counter()
    state["progress"] = time.monotonic()
    state["step"](0)
    while not state["done"]:
        ex.spin_until_future_complete(finished, timeout_sec=1.0)
        if time.monotonic() - state["progress"] > 60.0:
            raise SystemExit(f"the bare loop stalled at sample {state['k']} of {steps} (a message lost before its match?)")
    loop_s = state["t1"] - state["t0"]
    # the other nodes of this process take what is still on its way (the recorder's last messages)
    end = time.monotonic() + 30.0
    while not complete() and time.monotonic() < end:
        ex.spin_once(timeout_sec=0.05)
    if work and "recorder" in roles:
        handover.put(None)
        writer.join()
    finish()
    print(json.dumps({"loop_s": loop_s}), flush=True)
else:
    end, told = time.monotonic() + float(sys.argv[5]), False
    while time.monotonic() < end and not stop:
        ex.spin_until_future_complete(finished, timeout_sec=0.1)  # never completed here: C++ spins for 0.1 s
        if not told and complete():  # the parent waits for this before it stops the process
            write_counts(True)
            told = True
    if work and "recorder" in roles:
        handover.put(None)
        writer.join()
    finish()
ex.shutdown()
rclpy.shutdown()
"""


# ---- the topology, from a run of the scenario ------------------------------------------------

def _absolute(topic: str) -> str:
    return topic if topic.startswith("/") else "/" + topic


def _probe_run(py: str, scenario: str, seconds: float, out: Path) -> Path:
    """``sappc run`` of ``scenario`` cut to ``seconds`` (composed), into ``out``; its run directory."""
    base = Path(scenario)
    extends = str(base.resolve()) if base.suffix in (".yaml", ".yml") and base.is_file() else f"{scenario}.yaml"
    short = out / "probe.yaml"
    short.write_text(f"extends: {extends}\nname: {base.stem}_floor_probe\nduration_s: {seconds!r}\n")
    run_dir = out / "run"
    proc = subprocess.run([py, "-m", "sappc", "run", str(short), "--compose", "--out", str(run_dir)], cwd=paired.ROOT,
                          env={**os.environ, "PYTHONPATH": str(paired.ROOT / "src")}, capture_output=True, text=True, timeout=900)
    # 4: the run's requirements are not met (a few seconds of the experiment): the run itself is complete
    if proc.returncode not in (0, 4) or not (run_dir / "counts").is_dir():
        raise SystemExit(f"the probe run (sappc run {short} --compose) failed with status {proc.returncode}:\n{proc.stderr[-3000:]}")
    return run_dir


def _bag(run_dir: Path) -> dict[str, dict[str, Any]]:
    """Per topic of the run's bag: its type, its last message's CDR bytes and every stamp [ns]."""
    from mcap.reader import make_reader

    files = sorted((run_dir / "bag").glob("*.mcap"))
    if len(files) != 1:
        raise SystemExit(f"{run_dir / 'bag'}: expected one MCAP file, found {[f.name for f in files]}")
    topics: dict[str, dict[str, Any]] = {}
    with open(files[0], "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            t = topics.setdefault(channel.topic, {"type": schema.name if schema is not None else "", "stamps": []})
            t["raw"] = message.data
            t["stamps"].append(message.log_time)
    return topics


def _slot(type_name: str, raw: bytes, stamp_ns: int) -> tuple[str, int]:
    """Where a message of ``type_name`` carries its sample's time: the header's stamp (or ``/clock``'s
    clock) right after the CDR encapsulation, or ``data[0]`` of a ``Float64MultiArray`` (its offset
    found by writing a marker into the message); checked against the real message's own time."""
    import importlib
    import struct

    from rclpy.serialization import deserialize_message, serialize_message

    pkg, _, name = type_name.split("/")
    cls = getattr(importlib.import_module(f"{pkg}.msg"), name)
    first = next(iter(cls.get_fields_and_field_types()))
    if first in ("header", "clock"):
        sec, ns = struct.unpack_from("<iI", raw, 4)
        if sec * 1_000_000_000 + ns != stamp_ns:
            raise SystemExit(f"{type_name}: the stamp at byte 4 ({sec} s {ns} ns) is not the bag's {stamp_ns} ns")
        return ("clock" if first == "clock" else "stamp", 4)
    if type_name == "std_msgs/msg/Float64MultiArray":
        msg = deserialize_message(raw, cls)
        marker = 1234567.890625
        msg.data[0] = marker
        off = bytes(serialize_message(msg)).find(struct.pack("<d", marker))
        if off < 0 or abs(struct.unpack_from("<d", raw, off)[0] * 1e9 - stamp_ns) > 1e3:
            raise SystemExit(f"{type_name}: data[0] is not the message's time (the contract's label) at byte {off}")
        return ("f64", off)
    raise SystemExit(f"{type_name}: no known place for the sample's time (a header, /clock, or a Float64MultiArray's data[0])")


def _contract_qos() -> dict[str, Any]:
    """:func:`sappc_msgs_py.contract.qos_profile` (every topic's QoS), as the node processes build it."""
    sys.path.insert(0, str(paired.ROOT / "src"))
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy

    from sappc_msgs_py.contract import qos_profile

    q = qos_profile()
    if (q.reliability, q.durability, q.history) != (ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE, HistoryPolicy.KEEP_LAST):
        raise SystemExit(f"the contract's QoS changed ({q}): extend _NODE's qos()")
    return {"reliability": "reliable", "durability": "volatile", "history": "keep_last", "depth": q.depth}


def _topology(run_dir: Path, steps: int, ahead: int, probe_s: float | None) -> tuple[dict[str, Any], dict[str, Any]]:
    """(the bare graph's spec for the node processes, its description and self-check for the JSON)."""
    import yaml

    params = {name.strip("/"): p["ros__parameters"] for name, p in yaml.safe_load((run_dir / "params.yaml").read_text()).items()}
    composition = json.loads((run_dir / "composition.json").read_text())
    counts = {p.stem: {_absolute(t): n for t, n in json.loads(p.read_text()).items()} for p in sorted((run_dir / "counts").glob("*.json"))}
    samples = int(json.loads((run_dir / "logs" / "timing.json").read_text())["samples"])
    bag = _bag(run_dir)
    dt_ns = round(float(params["plant"]["control_period_s"]) * 1e9)
    if params["plant"].get("mode", "lockstep") != "lockstep":
        raise SystemExit(f"{run_dir}: not a lockstep run")

    order = [c["name"] for c in composition]
    remaps: dict[str, dict[str, str]] = {}
    for c in composition:
        args, pairs = c["args"], {}
        for i, a in enumerate(args[:-1]):
            if a == "-r" and not args[i + 1].startswith("__"):
                src, dst = args[i + 1].split(":=")
                pairs[_absolute(src)] = _absolute(dst)
        remaps[c["name"]] = pairs

    # publishers: each node's expected_subscribers (the topics it publishes, to how many subscribers)
    publisher: dict[str, str] = {}
    expected: dict[str, int] = {}
    for role in order:
        if role == "recorder":
            continue
        entries = params[role].get("expected_subscribers", [])
        for entry in entries:
            topic, _, n = entry.rpartition("=")
            topic = _absolute(topic)
            if topic.startswith("/fault/"):
                raise SystemExit(f"{role} publishes {topic}: fault relays are not modelled by the bare graph")
            publisher[topic], expected[topic] = role, int(n)
        if set(counts.get(role, {})) != {t for t, r in publisher.items() if r == role}:
            raise SystemExit(f"{role}: published {sorted(counts.get(role, {}))} in the run, its expected_subscribers name "
                             f"{sorted(t for t, r in publisher.items() if r == role)}")
    recorded = [_absolute(t) for t in params["recorder"]["topics"]]
    if set(recorded) != set(publisher) or set(bag) != set(publisher):
        raise SystemExit(f"the recorder's topics {sorted(recorded)} or the bag's {sorted(bag)} are not the published {sorted(publisher)}")

    # schedule: every sample, or every `period` samples from sample 0, which must give the run's count exactly
    period: dict[str, int] = {}
    for topic, recorded_topic in bag.items():
        stamps = recorded_topic["stamps"]
        ks = [round(s / dt_ns) for s in stamps]
        if any(k * dt_ns != s for k, s in zip(ks, stamps)) or ks != sorted(set(ks)):
            raise SystemExit(f"{topic}: stamps off the sample grid, or repeated")
        p = 1 if len(ks) < 2 else int(statistics.median(b - a for a, b in zip(ks, ks[1:])))
        if ks != list(range(0, samples, p)) or counts[publisher[topic]][topic] != len(ks):
            raise SystemExit(f"{topic}: published at samples {ks[:8]}... ({len(ks)} of {samples}), not every {p}th from 0")
        period[topic] = p

    # the roles: the inputs each takes (remapped as in the run), the outputs in the node's order
    roles: dict[str, dict[str, Any]] = {}
    subscribers: dict[str, list[str]] = {t: [] for t in publisher}
    for role in order:
        own = [t for t, r in publisher.items() if r == role]
        if role == "recorder":
            roles[role] = {"kind": "recorder", "subscribes": recorded}
            for t in recorded:
                subscribers[t].append(role)
            continue
        if role not in _ROLE_INPUTS:
            raise SystemExit(f"node {role} of the run has no entry in _ROLE_INPUTS")
        ins = {k: list(v) for k, v in _ROLE_INPUTS[role].items()}
        if role == "plant":
            p = params["plant"]
            ins["gates"] += (["/disturbance/torque"] if p.get("use_disturbance_topic") else []) \
                + (["/control/dipole"] if p.get("use_dipole_topic") else [])
        ins = {k: [remaps[role].get(t, t) for t in v] for k, v in ins.items()}
        for t in (t for v in ins.values() for t in v):
            if t not in subscribers:
                raise SystemExit(f"{role} subscribes to {t}, which no node of the run publishes")
            subscribers[t].append(role)
        if role == "plant":
            rank = {t: i for i, t in enumerate(_PLANT_ORDER)}
            kind = {"kind": "plant", "outputs": sorted((t for t in own if t not in _PLANT_AFTER_INPUTS), key=lambda t: rank.get(t, len(rank))),
                    "after": [t for t in own if t in _PLANT_AFTER_INPUTS]}
        elif "trigger" in ins:
            kind = {"kind": "ahead", "outputs": own}
        else:
            rank = {t: i for i, t in enumerate(_ESTIMATOR_ORDER)}
            kind = {"kind": "gated", "outputs": sorted(own, key=lambda t: rank.get(t, -1)) if role == "estimator" else own}
        roles[role] = {**kind, "gates": ins.get("gates", []), "scheduled": ins.get("scheduled", []), "listens": ins.get("listens", []),
                       "trigger": ins.get("trigger", [])}
    # expected_subscribers is what a publisher waits for before its first message: a subscriber it
    # does not wait for is no error of the table (noted in the JSON), one missing from the table is
    fewer = {t: (len(subscribers[t]), n) for t, n in expected.items() if len(subscribers[t]) < n}
    if fewer:
        raise SystemExit(f"the bare graph has fewer subscriptions than the run's publishers wait for (bare, expected_subscribers): {fewer}")
    unwaited = {t: {"subscribers": subscribers[t], "expected_subscribers": n} for t, n in expected.items() if len(subscribers[t]) > n}

    topics = {t: {"type": bag[t]["type"], "raw_hex": bag[t]["raw"].hex(), "slot": _slot(bag[t]["type"], bag[t]["raw"], bag[t]["stamps"][-1]),
                  "period": period[t]} for t in publisher}
    plant = {"inertia_kg_m2": [float(v) for v in params["plant"]["inertia_kg_m2"]], "rk4_substeps": int(params["plant"].get("rk4_substeps", 1))}
    spec = {"steps": steps, "dt_ns": dt_ns, "ahead": ahead, "topics": topics, "roles": roles, "subscribers": {t: len(s) for t, s in subscribers.items()},
            "params_yaml": (run_dir / "params.yaml").read_text(), "plant": plant,
            "qos": _contract_qos(), "recorder_qos": {"reliability": "reliable", "durability": "volatile", "history": "keep_all", "depth": 0}}
    table = {t: {"type": bag[t]["type"], "bytes": len(bag[t]["raw"]), "publisher": publisher[t], "subscribers": subscribers[t],
                 "period_samples": period[t], "probe_run_count": counts[publisher[t]][t]} for t in publisher}
    described = {"run_dir": str(run_dir), "probe_run": probe_s is not None, "probe_s": probe_s, "probe_samples": samples, "nodes": order, "remaps": {r: m for r, m in remaps.items() if m},
                 "topics": table, "subscribers_not_waited_for": unwaited}
    return spec, described


def _scheduled(spec: dict[str, Any], steps: int) -> tuple[dict[str, int], int]:
    """(messages per topic over ``steps`` samples, deliveries) as the schedule says."""
    msgs = {t: len(range(0, steps, v["period"])) for t, v in spec["topics"].items()}
    return msgs, sum(n * spec["subscribers"][t] for t, n in msgs.items())


def _check(spec: dict[str, Any], counts: list[dict[str, Any]]) -> dict[str, Any]:
    """The messages a bare run published and delivered per topic against its schedule."""
    published: dict[str, int] = {}
    delivered: dict[str, int] = {}
    for c in counts:
        for t, n in c["published"].items():
            published[t] = published.get(t, 0) + n
        for per_role in c["received"].values():
            for t, n in per_role.items():
                delivered[t] = delivered.get(t, 0) + n
    msgs, _ = _scheduled(spec, spec["steps"])
    bad = {t: {"published": published.get(t, 0), "delivered": delivered.get(t, 0), "scheduled": n, "subscribers": spec["subscribers"][t]}
           for t, n in msgs.items()
           if published.get(t, 0) != n or delivered.get(t, 0) != n * spec["subscribers"][t]}
    work: dict[str, int] = {}
    for c in counts:
        for k, n in c.get("work", {}).items():
            work[k] = work.get(k, 0) + n
    return {"messages": sum(published.values()), "deliveries": sum(delivered.values()), "mismatched_topics": bad,
            "complete": all(c.get("complete") for c in counts), "work": work}


# ---- the two layouts ----------------------------------------------------------------------------

def _env(domain: int, log_dir: Path) -> dict[str, str]:
    """The environment of ``sappc run``'s nodes (sappc.graph.launch.isolated_environment): the domain,
    discovery on this host only, the project's Fast DDS profile (fast discovery), a log directory."""
    return {**os.environ, "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
            "FASTRTPS_DEFAULT_PROFILES_FILE": str(paired.ROOT / "src" / "sappc" / "graph" / "fastdds_profile.xml"),
            "ROS_LOG_DIR": str(log_dir), "PYTHONUNBUFFERED": "1"}


def _composed(py: str, spec_path: Path, spec: dict[str, Any], env: dict[str, str], mode: str, tmp: Path) -> tuple[float, dict[str, Any]]:
    counts = tmp / "counts_composed.json"
    out = subprocess.run([py, "-c", _NODE, str(spec_path), ",".join(spec["roles"]), mode, str(counts), "0"], env=env, capture_output=True,
                         text=True, timeout=900)
    if out.returncode != 0:
        raise SystemExit(f"the composed floor failed:\n{out.stderr[-3000:]}")
    return float(json.loads(out.stdout.strip().splitlines()[-1])["loop_s"]), _check(spec, [json.loads(counts.read_text())])


def _complete(path: Path) -> bool:
    try:
        return bool(json.loads(path.read_text())["complete"])
    except (OSError, ValueError):
        return False


def _processes(py: str, spec_path: Path, spec: dict[str, Any], env: dict[str, str], mode: str, tmp: Path) -> tuple[float, dict[str, Any]]:
    others = [r for r in spec["roles"] if r != "plant"]
    files = {r: tmp / f"counts_{r}.json" for r in spec["roles"]}
    logs = {r: tmp / f"{r}.log" for r in others}
    procs = []
    for role in others:
        with open(logs[role], "w") as log:
            procs.append(subprocess.Popen([py, "-c", _NODE, str(spec_path), role, mode, str(files[role]), "900"], env=env,
                                          stdout=subprocess.DEVNULL, stderr=log))
    try:
        out = subprocess.run([py, "-c", _NODE, str(spec_path), "plant", mode, str(files["plant"]), "0"], env=env, capture_output=True,
                             text=True, timeout=900)
        if out.returncode != 0:
            raise SystemExit(f"the {len(spec['roles'])}-process floor failed:\n{out.stderr[-3000:]}")
        end = time.monotonic() + 30.0  # every process has taken what the schedule sends it (the recorder's last messages)
        while time.monotonic() < end and not all(_complete(files[r]) for r in others):
            time.sleep(0.05)
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.wait(timeout=60)
    for role, f in files.items():
        if not f.exists():
            raise SystemExit(f"the {role} process of the floor wrote no counts:\n{logs[role].read_text()[-3000:] if role in logs else ''}")
    return float(json.loads(out.stdout.strip().splitlines()[-1])["loop_s"]), _check(spec, [json.loads(f.read_text()) for f in files.values()])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_tracking", help="a bundled scenario's name or a scenario file (default paper_tracking)")
    parser.add_argument("--steps", type=int, default=6001, help="samples (default 6001: experiment 1, 60 s at 100 Hz)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--from-run", type=Path, default=None,
                        help="take the graph from this run directory (sappc run SCENARIO --compose --out DIR) instead of a probe run")
    parser.add_argument("--probe-s", type=float, default=3.0, help="the probe run's duration [s] (default 3: three estimator health messages)")
    parser.add_argument("--ahead", type=int, default=1, choices=(0, 1),
                        help="samples the reference and the injector publish ahead of /clock (1: the nodes' GridCursor; 0: on the tick)")
    parser.add_argument("--modes", default="messages,serialized", help="comma-separated: messages, serialized, work")
    env_domain = os.environ.get("SAPPC_BENCH_DOMAIN")
    parser.add_argument("--domain-id", type=int, default=int(env_domain) if env_domain else None,
                        help="ROS domain of the bare graph (default: SAPPC_BENCH_DOMAIN, else a free one, claimed as sappc run claims it)")
    args = parser.parse_args()
    py = paired.python_of(paired.ROOT)
    if Path(sys.executable).resolve() != Path(py).resolve() and os.environ.get("SAPPC_FLOOR_REEXEC") != "1":
        os.execve(py, [py, *sys.argv], {**os.environ, "SAPPC_FLOOR_REEXEC": "1"})  # yaml, mcap, rclpy: the checkout's venv
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="sappc-floor-") as tmp_name:
        tmp = Path(tmp_name)
        run_dir = args.from_run if args.from_run is not None else _probe_run(py, args.scenario, args.probe_s, tmp)
        spec, described = _topology(run_dir, args.steps, args.ahead, None if args.from_run is not None else args.probe_s)
        spec_path = tmp / "graph.json"
        spec_path.write_text(json.dumps(spec))
        per_step_msgs = sum(1 / v["period"] for v in spec["topics"].values())
        per_step_deliveries = sum(spec["subscribers"][t] / v["period"] for t, v in spec["topics"].items())
        msgs, deliveries = _scheduled(spec, args.steps)
        probe_msgs, _ = _scheduled(spec, described["probe_samples"])
        n_proc = len(spec["roles"])
        processes = f"{_NUMBERS[n_proc] if n_proc < len(_NUMBERS) else n_proc}_processes"
        result: dict[str, Any] = {
            "row": "graph_floor_bare_rclpy", "date": time.strftime("%Y-%m-%d"), "machine": paired.machine(), "commit": paired.commit(paired.ROOT),
            "scenario": args.scenario, "steps": args.steps, "topics": len(spec["topics"]), "nodes": list(spec["roles"]),
            "messages_per_step": per_step_msgs, "deliveries_per_step": per_step_deliveries,
            "messages_scheduled": sum(msgs.values()), "deliveries_scheduled": deliveries, "repeats": args.repeats, "ahead": args.ahead,
            "graph": described,
            "self_check_probe_run": {"samples": described["probe_samples"],
                                     "schedule_gives_run_counts": all(probe_msgs[t] == v["probe_run_count"] for t, v in described["topics"].items()),
                                     "run_messages": sum(v["probe_run_count"] for v in described["topics"].values()),
                                     "schedule_messages": sum(probe_msgs.values())},
        }
        print(f"bench_graph_floor: {args.scenario}: {len(spec['topics'])} topics, {n_proc} nodes, {per_step_msgs:.4g} messages and "
              f"{per_step_deliveries:.4g} deliveries per sample (from {run_dir})", file=sys.stderr, flush=True)
        with claim_domain_id(args.domain_id, source="--domain-id") as domain:  # as sappc run claims it
            env = _env(domain, tmp / "logs")
            result["domain_id"] = domain
            for mode in args.modes.split(","):
                for name, fn in (("composed", _composed), (processes, _processes)):
                    loops, checks = [], []
                    for _ in range(args.repeats):
                        loop, check = fn(py, spec_path, spec, env, mode, tmp)
                        loops.append(loop)
                        checks.append(check)
                        print(f"bench_graph_floor: {name} {mode}: {loop:.3f} s ({loop / args.steps * 1e6:.0f} us a sample)", file=sys.stderr,
                              flush=True)
                    med = statistics.median(loops)
                    result[f"{name}_{mode}"] = {
                        "loop_s": {"median": med, "min": min(loops), "max": max(loops), "runs": loops},
                        "us_per_step": med / args.steps * 1e6, "messages_per_s": sum(msgs.values()) / med, "processes": 1 if name == "composed" else n_proc,
                        "messages_per_step": per_step_msgs, "deliveries_per_step": per_step_deliveries,
                        "measured": {"messages": [c["messages"] for c in checks], "deliveries": [c["deliveries"] for c in checks],
                                     **({"work_done": [c["work"] for c in checks]} if mode == "work" else {}),
                                     "as_scheduled": all(not c["mismatched_topics"] and c["complete"] for c in checks),
                                     "mismatched_topics": next((c["mismatched_topics"] for c in checks if c["mismatched_topics"]), {})},
                    }
    result["load_average_1min"] = {"before": load_before, "after": os.getloadavg()[0]}
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

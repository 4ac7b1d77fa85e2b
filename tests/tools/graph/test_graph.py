"""The whole node graph end to end, each node its own process on an isolated domain.

- lockstep experiment 1 through ``sappc run`` equals the offline runner (q_ev within 1e-9, the
  issue's bound; measured ~3e-17), the bag opens with ``rosbags`` and ``mcap_ros2`` and counts
  exactly what was published;
- the sudden fault through the graph: SAPPC returns into its band;
- a plant written only against the contract drives ``python -m sappc_controller``;
- SIGINT to ``sappc run`` finalises the bag, leaves no process and no shared memory of its own behind
  (:class:`shm_watch.ShmWatch`: what the run's processes used, not the whole machine's /dev/shm);
- a SIGKILLed recorder leaves a bag whose flushed part is readable (real time: test_realtime_graph.py).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from sappc.bag.read import BagError, bag_run, read_bag
from sappc.scenario import load_scenario
from sappc.offline.simulate import simulate

from conftest import ROOT, SAPPC, SCENARIOS
from shm_watch import ShmWatch

pytestmark = pytest.mark.slow


def _children_of(pid: int) -> list[int]:
    out = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True)
    return [int(x) for x in out.stdout.split()]


def _rosbags_counts(bag_dir: Path) -> dict[str, int]:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    counts: dict[str, int] = {}
    with AnyReader([bag_dir], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, _, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)  # every message decodes
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
    return counts


def test_lockstep_graph_equals_the_offline_runner(tracking_run) -> None:  # type: ignore[no-untyped-def]
    out, report, _ = tracking_run
    offline = simulate(load_scenario(SCENARIOS / "paper_tracking.yaml"))
    run = bag_run(read_bag(out / "bag"))
    q_ev_graph = run.history.q_ev[:, 0]
    assert q_ev_graph.shape == offline.history.q_ev[:, 0].shape
    assert np.abs(q_ev_graph - offline.history.q_ev[:, 0]).max() <= 1e-9
    for key, value in offline.metrics.items():
        if key == "wall_time_s":
            continue
        got = report["metrics"][key]
        if isinstance(value, float):
            assert got == pytest.approx(value, abs=1e-9), key
        else:
            assert got == value, key


def test_bag_opens_with_rosbags_and_mcap_ros2_and_counts_what_was_published(tracking_run) -> None:  # type: ignore[no-untyped-def]
    out, report, watch = tracking_run
    published = report["published"]
    assert published["/state/attitude"] == 6001 and published["/control/torque"] == 6001
    assert _rosbags_counts(out / "bag") == {t: n for t, n in published.items() if n}
    from mcap_ros2.reader import read_ros2_messages

    first = next(iter(read_ros2_messages(str(next((out / "bag").glob("*.mcap"))), topics=["/state/attitude"])))
    assert first.ros_msg.header.frame_id == "inertial"
    meta = (out / "bag" / "metadata.yaml").read_text()
    assert "version: 9" in meta and "RIHS01_" in meta
    channels = {t["topic_metadata"]["name"]: t["message_count"]
                for t in yaml.safe_load(meta)["rosbag2_bagfile_information"]["topics_with_message_count"]}
    assert channels == {t: n for t, n in published.items() if n} and len(channels) == 11  # no empty channel
    assert (out / "bag" / "scenario.yaml").exists() and (out / "bag" / "params.yaml").exists()
    watch.assert_clean()  # no process of the run alive, none of its shared memory left in /dev/shm


def test_the_composed_graph_records_the_same_bag_byte_for_byte(tracking_run, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """``sappc run --compose`` (every node in one process, one executor) and the five processes:
    the same MCAP file byte for byte (a lockstep bag is on simulated time and in stamp order;
    the run's files are recorded with paths relative to the run directory), the same
    metadata.yaml and counts, the same metrics; one process was started instead of five.
    ``--json -``: the summary is all that comes out on stdout."""
    out, report, _ = tracking_run
    composed = tmp_path / "composed"  # given relative to the working directory (a composed run once failed with one)
    proc = subprocess.run([*SAPPC, "run", str(SCENARIOS / "paper_tracking.yaml"), "--compose", "--out", "composed", "--json", "-"],
                          capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    composed_report = json.loads(proc.stdout)  # --json -: the JSON alone on stdout, the table and the nodes' output on stderr
    assert "through the ROS 2 graph (composed)" in proc.stderr and not (tmp_path / "-").exists()
    assert composed_report["composed"] is True and report["composed"] is False
    assert (composed / "bag" / "bag_0.mcap").read_bytes() == (out / "bag" / "bag_0.mcap").read_bytes()
    assert (composed / "bag" / "metadata.yaml").read_text() == (out / "bag" / "metadata.yaml").read_text()
    assert composed_report["published"] == report["published"] and composed_report["recorded"] == report["recorded"]
    timing = ("wall_time_s", "startup_s", "first_sample_after_nodes_up_s")
    assert {k: v for k, v in composed_report["metrics"].items() if k not in timing} == {k: v for k, v in report["metrics"].items() if k not in timing}
    logs = {p.stem for p in (composed / "logs").glob("*.log")}  # with rcl's own python_<pid>_<time>.log
    assert "composed" in logs and not logs & {"plant", "controller", "reference", "injector", "recorder"}


def test_a_lockstep_bag_is_on_simulated_time(tracking_run) -> None:  # type: ignore[no-untyped-def]
    """Every message's log and publish time is its own stamp (the time it belongs to), so a
    player's timeline is the experiment's 0 .. 60 s; the closed file is in stamp order."""
    from mcap.reader import make_reader

    from sappc_msgs_py.convert import cdr_stamp_ns

    out, _, _ = tracking_run
    with (out / "bag" / "bag_0.mcap").open("rb") as f:
        reader = make_reader(f)
        last = -1
        n = 0
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert message.log_time == message.publish_time == cdr_stamp_ns(schema.name, message.data), channel.topic
            assert message.log_time >= last
            last = message.log_time
            n += 1
        stats = reader.get_summary().statistics
    assert n == 66011 and stats.message_start_time == 0 and stats.message_end_time == 60 * 10**9


def test_fault_through_the_graph_returns_into_the_band(tmp_path) -> None:
    out = tmp_path / "fault"
    proc = subprocess.run([*SAPPC, "run", str(SCENARIOS / "paper_fault.yaml"), "--out", str(out), "--json", str(tmp_path / "m.json")],
                          capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    m = json.loads((tmp_path / "m.json").read_text())["metrics"]
    assert m["left_constraint_after_fault"] is True and m["returned_to_constraint"] is True
    assert 50.0 < m["returned_at_s"] < 80.0


def test_a_plant_written_against_the_contract_drives_the_controller(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """... recorded, and its bag analysed: report (no scenario in the bag: default metric
    settings) and rerun (with the controller's parameters file: every torque identical)."""
    from contract_plant import run_contract_plant

    env = dict(os.environ)  # the fixture set the domain, discovery range and profile
    bag_dir = tmp_path / "bag"
    rec = subprocess.Popen([sys.executable, "-m", "sappc.graph.recorder", "--ros-args", "-p", f"output_dir:={bag_dir}"],
                           env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=ROOT)
    params = ROOT / "config" / "controller_sappc.yaml"
    ctrl = subprocess.Popen([sys.executable, "-m", "sappc_controller", "--ros-args", "--params-file", str(params),
                             "-p", 'expected_subscribers:=["control/torque=2","controller/diagnostics=1"]'],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=ROOT)
    steps = 2501
    try:
        q0 = np.array([0.3254, 0.4068, -0.3254, 0.7891])
        q, tq = run_contract_plant(ros_context, q0 / np.linalg.norm(q0), steps=steps, subscribers=2)
    finally:
        ctrl.send_signal(signal.SIGINT)
        log = ctrl.communicate(timeout=30)[0].decode()
        rec.send_signal(signal.SIGINT)
        rec_log = rec.communicate(timeout=30)[0].decode()
    assert ctrl.returncode == 0, log
    assert rec.returncode == 0, rec_log
    assert np.all(np.isfinite(tq)) and np.abs(tq).max() <= 0.5
    # requirement 1 of the paper: max |q_ev,i| < 1e-3 by t = 20 s (here q_ev = the attitude's vector part)
    assert np.abs(q[2000:, :3]).max() < 1e-3, np.abs(q[2000:, :3]).max()
    assert q[0, 3] > 0 and abs(q[-1, 3]) > 0.999

    from sappc.analysis.report import analyse_bag

    a = analyse_bag(bag_dir)
    assert a.scenario is None and a.metrics is not None
    assert a.bag.counts["/state/attitude"] == steps and a.bag.counts["/control/torque"] == steps
    assert np.array_equal(a.run.history.q_BN[:, 0], q)  # the bag holds what the plant flew
    assert a.metrics["settling_time_s"] < 20.0 and a.metrics["finite"]
    proc = subprocess.run([*SAPPC, "rerun", str(bag_dir), "--params", str(params), "--json", str(tmp_path / "rerun.json")],
                          capture_output=True, text=True, cwd=ROOT)
    rerun = json.loads((tmp_path / "rerun.json").read_text())
    assert rerun["mode"] == "lockstep" and rerun["samples"] == steps and rerun["identical"] == steps, proc.stdout


@pytest.mark.parametrize(("stop", "second_sigint_after_s"), [(signal.SIGINT, None), (signal.SIGINT, 0.3), (signal.SIGTERM, None)],
                         ids=["one_sigint", "two_sigints_0.3_s_apart", "sigterm"])
def test_sigint_finalises_the_bag_and_leaves_nothing_behind(tmp_path, stop, second_sigint_after_s) -> None:  # type: ignore[no-untyped-def]
    """One Ctrl-C, a second one 0.3 s later while the nodes are being stopped, or a SIGTERM (``kill``):
    every node is stopped, the bag is finalised and no shared-memory segment is left."""
    import yaml

    scenario = yaml.safe_load((SCENARIOS / "paper_tracking.yaml").read_text())
    scenario["duration_s"] = 600.0  # long enough that no machine load lets it end before the signal
    path = tmp_path / "long.yaml"
    path.write_text(yaml.safe_dump(scenario))
    out = tmp_path / "int"
    with ShmWatch() as watch:
        proc = subprocess.Popen([*SAPPC, "run", str(path), "--out", str(out)],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=ROOT)
        watch.add(proc.pid)
        deadline = time.monotonic() + 120
        # wait until the run is under way (the recorder has flushed messages), then interrupt
        while time.monotonic() < deadline:
            mcaps = list((out / "bag").glob("*.mcap"))
            if mcaps and mcaps[0].stat().st_size > 200_000:
                break
            time.sleep(0.1)
        children = _children_of(proc.pid)
        assert len(children) == 5
        proc.send_signal(stop)
        if second_sigint_after_s is not None:
            time.sleep(second_sigint_after_s)
            proc.send_signal(signal.SIGINT)
        log = proc.communicate(timeout=120)[0].decode()
    assert proc.returncode == 130, log
    watch.assert_clean()  # the five nodes and the launcher exited; no shared memory of theirs left
    counts = _rosbags_counts(out / "bag")  # finalised: rosbags opens it through metadata.yaml
    bag = read_bag(out / "bag")
    assert bag.truncated is None and counts == {t: n for t, n in bag.counts.items()}
    assert 0 < counts["/state/attitude"] < 60001


def _flushed(bag_dir: Path) -> int:
    """Messages readable in the bag now (0 before the file exists)."""
    try:
        return read_bag(bag_dir).counts.get("/state/rate", 0)
    except BagError:
        return 0


@pytest.mark.parametrize("mode", ["realtime", "lockstep"])
def test_a_sigkilled_recorder_leaves_its_flushed_messages_readable(ros_context, tmp_path, mode) -> None:  # type: ignore[no-untyped-def]
    """In both modes (wall-time or simulated-time bags) the recorder writes each message as it
    arrives and flushes every FLUSH_PERIOD_S of wall time: all 500 acknowledged messages become
    readable, and a SIGKILL then loses none of them."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from sappc_msgs_py import contract as c
    from sappc_msgs_py.convert import vector3_msg

    bag_dir = tmp_path / "bag"
    watch = ShmWatch().__enter__()  # the killed recorder's shared memory, removed below (only its own)
    rec = subprocess.Popen([sys.executable, "-m", "sappc.graph.recorder", "--ros-args", "-p", f"output_dir:={bag_dir}", "-p", f"mode:={mode}"],
                           env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=ROOT)
    watch.add(rec.pid)
    readable = 500
    node = Node("pub", context=ros_context)
    pub = node.create_publisher(c.STATE_RATE.msg_class, c.STATE_RATE.name, c.qos_profile())
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    deadline = time.monotonic() + 30
    while pub.get_subscription_count() < 1:
        assert time.monotonic() < deadline
        ex.spin_once(timeout_sec=0.02)
    for k in range(500):
        pub.publish(vector3_msg([k, 0.0, 0.0], k * 0.01, c.STATE_RATE))
    assert pub.wait_for_all_acked()
    while _flushed(bag_dir) < readable:
        assert time.monotonic() < deadline, _flushed(bag_dir)
        time.sleep(0.05)
    rec.kill()
    rec.wait()
    watch.__exit__(None, None, None)
    assert watch.used, "the recorder used no shared memory: nothing to clean up was checked"
    ex.shutdown()
    node.destroy_node()
    watch.remove_left_behind()  # a SIGKILLed process cannot remove its own files; never the whole host's
    bag = read_bag(bag_dir)
    assert bag.truncated is not None  # no summary, no footer
    values = bag.series["/state/rate"].values[:, 0]
    assert values.size == readable and np.array_equal(values, np.arange(float(readable)))
    # rosbags and mcap's indexed reader need the footer: `sappc repair` writes it back (ros2 bag reindex)
    proc = subprocess.run([*SAPPC, "repair", str(bag_dir), "--json", str(tmp_path / "repair.json")], capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    repaired = json.loads((tmp_path / "repair.json").read_text())
    assert not repaired["was_complete"] and repaired["counts"]["/state/rate"] == readable
    assert _rosbags_counts(bag_dir)["/state/rate"] == readable  # through metadata.yaml, as rosbags opens a bag
    from mcap.reader import make_reader

    with (bag_dir / f"{bag_dir.name}_0.mcap").open("rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None  # the indexed reader's view
        rates = [m for _, ch, m in reader.iter_messages() if ch.topic == "/state/rate"]
    assert len(rates) == readable
    assert read_bag(bag_dir).truncated is None and np.array_equal(read_bag(bag_dir).series["/state/rate"].values[:, 0], values)

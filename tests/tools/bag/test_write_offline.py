"""An offline run's full-rate record as a bag (issue 47 item 4, :mod:`sappc.bag.write_offline`).

- read back (:func:`~sappc.bag.read.read_bag`, :func:`~sappc.bag.read.bag_run`), a run gives the
  offline History's recorded fields bit for bit (float64 through CDR is exact; the orbit's
  environmental torque is not published, NaN from a bag as from a graph bag), every stamp the
  plant's ``seconds_to_ns(k dt)``, and ``sappc report``'s metrics are the run's, every one;
- with the History's answers (``answer``, what the proposed field holds), the controller's
  diagnostics carry them: the bag's answers and summary are the run's, the input stamps the
  sample's for a computed answer, zero otherwise; an actuator fault's torque goes on the relay's
  topic;
- the topics are those a lockstep graph run of the same scenario records, less those the offline
  record does not hold (every bundled scenario, against ``sappc run``'s recorder parameters), with
  the recorder's types, channel metadata, chunk size and the controller node's parameters; a
  lockstep graph bag of experiment 1 has the same topics, types and stamps, its values within
  1e-12 (slow: it runs the graph);
- every message is what the nodes' encoders build (rclpy deserialises it to their message), and
  the bag opens with ``mcap`` (CRCs checked), ``mcap_ros2`` and ``rosbags``;
- written in blocks of any size (several sink calls, pieces and chunks cut anywhere) it is the
  same file, byte for byte, as written in one call.
"""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from sappc.bag import write_offline
from sappc.bag.errors import BagError
from sappc.bag.read import bag_run, read_bag
from sappc.bag.write_offline import UNRECORDED_TOPICS, OfflineBagWriter, controller_parameters, offline_topics
from sappc.offline import compiled_loop
from sappc.offline.simulate import simulate
from sappc.scenario import Scenario, load_scenario, read_scenario_mapping, scenario_from_mapping
from sappc_msgs_py import contract as c
from sappc_msgs_py import convert
from sappc_msgs_py.convert import seconds_to_ns

from conftest import SCENARIOS, cut_short

#: The History's fields a bag carries as the offline loop records them, bit for bit (``t`` is
#: counted from the first stamp in seconds by the reader; ``q_BR`` the reader recomputes from the
#: recorded reference and attitude, as for a graph bag).
RECORDED = ("q_BN", "omega_BN_B", "torque_B", "torque_cmd_B", "saturated", "disturbance_B", "rho", "band_lower", "band_upper",
            "eps", "z", "V", "wheel_speed_rad_s", "wheel_torque_Nm")
#: Columns of the orbit's record a bag carries: the true and the measured field, the rods' commands
#: (6:9, the environmental torque, is not published: NaN from any bag).
ORBIT_COLUMNS = np.r_[0:6, 9:12]


def _scenario(name: str, duration_s: float, **changes: Any) -> Scenario:
    raw = cut_short(read_scenario_mapping(SCENARIOS / name), duration_s)
    raw.update(changes)
    return scenario_from_mapping(raw, source=name)


def _record(scenario: Scenario, out: Path) -> Any:
    """``scenario`` run by ``simulate`` (no history kept) with a writer as its sink: the result."""
    writer = OfflineBagWriter(scenario, out)
    result = simulate(scenario, history="none", sinks=[writer])
    writer.close()
    return result


def _record_with_answers(scenario: Scenario, out: Path, block_samples: int = 97) -> np.ndarray:
    """``scenario`` run by the compiled loop in blocks, each History given the block's answers as
    ``answer`` (T, 1) (the field proposed for :class:`~sappc.evaluation.history.History`); the
    answers (T,)."""
    writer = OfflineBagWriter(scenario, out)
    answers = []
    for block in compiled_loop.run_blocks(compiled_loop.prepare(scenario, whole=False), 1, block_samples):
        h = block.history()
        h.answer = block.status.T  # type: ignore[attr-defined]  # the proposed field
        writer(h)
        answers.append(block.status[0].copy())
    writer.close()
    return np.concatenate(answers)


@pytest.mark.parametrize("name", ["paper_tracking.yaml", "paper_tracking_orbit.yaml", "paper_tracking_wheels.yaml",
                                  "flight_tracker_outage.yaml"])
def test_the_bag_reads_back_as_the_offline_run_bit_for_bit(name: str, tmp_path: Path) -> None:
    scenario = _scenario(name, 8.0)
    result = _record(scenario, tmp_path / "bag")
    offline = simulate(scenario).history  # the same run, its whole record kept
    assert offline is not None
    bag = read_bag(tmp_path / "bag")
    assert not bag.undecodable and bag.truncated is None
    run = bag_run(bag)
    got = run.history
    for field in RECORDED:
        a, b = getattr(offline, field), getattr(got, field)
        assert (a is None) == (b is None), field
        if a is not None:
            assert a.shape == b.shape and np.array_equal(a, b, equal_nan=True), field
    assert np.array_equal(offline.q_BR, got.q_BR, equal_nan=True) or np.nanmax(np.abs(offline.q_BR - got.q_BR)) <= 1e-15
    assert np.abs(got.t - offline.t).max() <= 1e-12  # (stamp - first) / 1e9 against k dt
    if offline.orbit is not None:
        assert got.orbit is not None
        assert np.array_equal(offline.orbit[..., ORBIT_COLUMNS], got.orbit[..., ORBIT_COLUMNS], equal_nan=True)
        assert np.isnan(got.orbit[..., 6:9]).all()
    if offline.estimate is not None:
        assert got.estimate is not None
        for f in dataclasses.fields(offline.estimate):
            a, b = getattr(offline.estimate, f.name), getattr(got.estimate, f.name)
            assert a is not None and b is not None and np.array_equal(a, b, equal_nan=True), f.name
    # the stamps: the plant's, every topic, every sample
    T = offline.t.size
    stamps = np.array([seconds_to_ns(k * scenario.control_period_s) for k in range(T)])
    for topic, series in bag.series.items():
        assert np.array_equal(series.stamps_ns, stamps), topic
        assert np.array_equal(series.log_time_ns, stamps), topic
    assert bag.counts == {"/" + t.name.lstrip("/"): T for t in offline_topics(scenario)}
    assert result.history is None  # the writer kept nothing of the run either: it wrote each block


def test_sappc_report_reads_the_offline_run_metrics_every_one(tmp_path: Path) -> None:
    from sappc.analysis.report import analyse_bag

    scenario = _scenario("paper_tracking_orbit.yaml", 20.0)
    result = _record(scenario, tmp_path / "bag")
    analysis = analyse_bag(tmp_path / "bag")  # the scenario embedded in the bag
    assert analysis.metrics is not None
    assert analysis.scenario is not None and analysis.scenario.duration_s == 20.0
    assert {k: v for k, v in result.metrics.items() if k != "wall_time_s"} == \
        {k: analysis.metrics[k] for k in result.metrics if k != "wall_time_s"}


def test_the_answers_the_stamps_and_an_actuator_fault(tmp_path: Path) -> None:
    """A held sample (a sensor dropout longer than a sample), zero answers (the watchdog before the
    estimate is confirmed), an actuator fault: the bag's answers are the run's."""
    faults = [{"kind": "sensor_dropout", "start_s": 1.0, "end_s": 1.2},
              {"kind": "actuator_bias", "bias_Nm": [0.01, 0.0, 0.0], "start_s": 2.0}]
    for name, changes in (("paper_tracking.yaml", {"faults": faults}), ("flight_prior_90deg.yaml", {})):
        scenario = _scenario(name, 4.0, **changes)
        out = tmp_path / name.removesuffix(".yaml")
        answers = _record_with_answers(scenario, out)
        bag = read_bag(out)
        run = bag_run(bag)
        assert np.array_equal(run.answer, answers)
        summary = simulate(scenario, history="none").controller_summary
        assert {k: v for k, v in run.controller_summary().items() if k != "rejected_inputs"} == \
            {k: v for k, v in summary.items() if k not in ("rejected_inputs", "rejected_by_reason")}
        assert len(set(answers.tolist())) > 1, name  # the run has answers of more than one kind
        d = bag.series["/controller/diagnostics"].values.reshape(-1, len(c.DIAGNOSTICS_LAYOUT), 3)
        labels = list(c.DIAGNOSTICS_LAYOUT)
        t_s = bag.series["/controller/diagnostics"].stamps_ns / 1e9
        computed = answers == c.ANSWER_COMMANDED
        state = d[:, labels.index("input_stamps_state_s")]
        reference = d[:, labels.index("input_stamps_reference_s")]
        assert np.array_equal(state[:, 0], np.where(computed, t_s, 0.0)) and np.array_equal(state[:, 2], np.zeros(t_s.size))
        assert np.array_equal(reference, np.where(computed, t_s, 0.0)[:, None].repeat(3, axis=1))
        assert np.array_equal(d[:, labels.index("status"), 1], (~computed).astype(float))
        assert np.isnan(d[:, labels.index("status"), 0]).all()  # the rejected count: not in the record
    fault = _scenario("paper_tracking.yaml", 4.0, faults=faults)
    topics = [t.name for t in offline_topics(fault)]
    assert "fault/control/torque" in topics and "control/torque" not in topics
    assert bag_run(read_bag(tmp_path / "paper_tracking")).torque_topic == "/fault/control/torque"


def test_without_answers_the_status_is_unknown(tmp_path: Path) -> None:
    """A History without ``answer`` (today's, or any made without the loop's record of them): the
    answer's code, the stale flag and the input stamps are NaN, not made up."""
    scenario = _scenario("paper_tracking.yaml", 1.0)
    history = simulate(scenario).history
    assert history is not None
    if "answer" in {f.name for f in dataclasses.fields(history)}:  # the field proposed for History
        no_answer: dict[str, Any] = {"answer": None}
        history = dataclasses.replace(history, **no_answer)
    with OfflineBagWriter(scenario, tmp_path / "bag") as writer:
        writer(history)
    d = read_bag(tmp_path / "bag").series["/controller/diagnostics"].values.reshape(-1, len(c.DIAGNOSTICS_LAYOUT), 3)
    labels = list(c.DIAGNOSTICS_LAYOUT)
    for label in ("status", "input_stamps_state_s", "input_stamps_reference_s"):
        assert np.isnan(d[:, labels.index(label)]).all(), label


def _graph_parameters(scenario: Scenario) -> dict[str, Any]:
    from sappc.graph.launch import node_parameters

    return node_parameters(scenario, scenario.controller, realtime=False,
                           paths={"scenario": "scenario.yaml", "bag": "bag", "counts": "counts", "params": "params.yaml",
                                  "end": "end"})


@pytest.mark.parametrize("path", sorted(SCENARIOS.glob("*.yaml")), ids=lambda p: p.stem)
def test_the_topics_are_the_graph_recorders_less_what_the_record_lacks(path: Path) -> None:
    scenario = load_scenario(path)
    params = _graph_parameters(scenario)
    graph = params["/recorder"]["ros__parameters"]["topics"]
    if scenario.modes is not None and c.MODE_STATUS.name not in graph:  # a graph without its mode node yet (issue 49): it records mode/status
        graph = [t.name for t in c.TOPICS + c.FAULT_TOPICS if t.name in {*graph, c.MODE_STATUS.name}]
    lacking = set(UNRECORDED_TOPICS) | {t.name for t in c.FAULT_TOPICS if t.name != "fault/control/torque"}
    if scenario.sensors is not None:
        lacking |= {c.STATE_ATTITUDE.name, c.STATE_RATE.name}  # the measurements
    if c.CONTROL_TORQUE.name in graph and "fault/control/torque" in graph:
        lacking.add(c.CONTROL_TORQUE.name)  # the answer before the actuator fault
    assert [t.name for t in offline_topics(scenario)] == [t for t in graph if t not in lacking]
    # the controller node's parameters, but the graph's plumbing
    node = dict(params["/controller"]["ros__parameters"])
    for key in ("expected_subscribers", "counts_file", "timing_file"):
        node.pop(key)
    # (as YAML: a NaN parameter, rpf.rho_e0 null, equals itself there)
    assert yaml.safe_dump(controller_parameters(scenario)) == yaml.safe_dump({"/controller": {"ros__parameters": node}})


def test_channels_schemas_metadata_and_chunks_as_the_recorder_writes_them(tmp_path: Path) -> None:
    from mcap.reader import make_reader

    from sappc.bag.rosbag2 import offered_qos_v9
    from sappc.graph.recorder import CHUNK_SIZE
    from sappc_msgs_py.schemas import schema_text, type_hash

    assert write_offline.CHUNK_SIZE_BYTES == CHUNK_SIZE
    scenario = _scenario("paper_tracking_orbit.yaml", 2.0)
    _record(scenario, tmp_path / "run")
    with (tmp_path / "run" / "run_0.mcap").open("rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
        assert summary is not None
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert header.profile == "ros2"
    qos = yaml.safe_dump(offered_qos_v9(), sort_keys=False)
    topics = offline_topics(scenario)
    assert [ch.topic for ch in summary.channels.values()] == ["/" + t.name.lstrip("/") for t in topics]
    for ch, topic in zip(summary.channels.values(), topics):
        schema = summary.schemas[ch.schema_id]
        assert (schema.name, schema.encoding, schema.data.decode(), ch.message_encoding) == \
            (topic.type_name, "ros2msg", schema_text(topic.type_name), "cdr")
        assert ch.metadata == {"offered_qos_profiles": qos, "topic_type_hash": type_hash(topic.type_name)}
    assert set(metadata) == {"sappc/scenario.yaml", "sappc/params.yaml", "rosbag2"}
    assert yaml.safe_load(metadata["sappc/scenario.yaml"]["text"]) == scenario.raw
    assert metadata["sappc/params.yaml"]["text"] == (tmp_path / "run" / "params.yaml").read_text()
    info = yaml.safe_load((tmp_path / "run" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info == yaml.safe_load(metadata["rosbag2"]["serialized_metadata"])
    assert info["relative_file_paths"] == ["run_0.mcap"] and info["message_count"] == 201 * len(topics)
    assert info["custom_data"] == {"sappc/scenario.yaml": "scenario.yaml", "sappc/params.yaml": "params.yaml"}
    assert summary.statistics is not None and summary.statistics.message_end_time == seconds_to_ns(2.0)
    assert all(ci.uncompressed_size <= write_offline.CHUNK_SIZE_BYTES for ci in summary.chunk_indexes)


def test_an_existing_directory_is_refused(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="already exists"):
        OfflineBagWriter(_scenario("paper_tracking.yaml", 1.0), tmp_path)


def test_it_opens_with_mcap_mcap_ros2_and_rosbags(tmp_path: Path) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.reader import read_ros2_messages
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    scenario = _scenario("paper_tracking_orbit.yaml", 3.0)
    _record(scenario, tmp_path / "bag")
    T, n_topics = 301, len(offline_topics(scenario))
    with (tmp_path / "bag" / "bag_0.mcap").open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        last, count = (-1, -1), 0
        for _, channel, message in reader.iter_messages(log_time_order=False):  # in the file's order: stamp, then channel
            assert message.log_time == message.publish_time and message.sequence == message.log_time // 10_000_000 + 1
            assert (message.log_time, channel.id) > last
            last = (message.log_time, channel.id)
            count += 1
    assert count == T * n_topics
    assert sum(1 for _ in read_ros2_messages(str(tmp_path / "bag" / "bag_0.mcap"))) == T * n_topics
    counts: dict[str, int] = {}
    with AnyReader([tmp_path / "bag"], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as bag:
        for conn, _, raw in bag.messages():
            bag.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
    assert counts == {"/" + t.name.lstrip("/"): T for t in offline_topics(scenario)}


def _node_message(topic: c.Topic, msg: Any, scenario: Scenario) -> Any:
    """What the node publishing ``topic`` builds from the values ``msg`` carries (its encoder in
    :mod:`sappc_msgs_py.convert`)."""
    stamp: Any = msg.clock if topic is c.CLOCK else msg.header.stamp if hasattr(msg, "header") else None  # (float arrays: none)
    if topic is c.CLOCK:
        return convert.clock_msg(convert.stamp_to_time(stamp))
    if topic.type_name.endswith("QuaternionStamped"):
        q = np.array([msg.quaternion.x, msg.quaternion.y, msg.quaternion.z, msg.quaternion.w])
        return convert.quaternion_msg(q, stamp, topic) if np.isfinite(q).all() else convert.no_data_msg(topic, stamp)
    if topic.type_name.endswith("Vector3Stamped"):
        v = np.array([msg.vector.x, msg.vector.y, msg.vector.z])
        return convert.vector3_msg(v, stamp, topic) if np.isfinite(v).all() else convert.no_data_msg(topic, stamp)
    if topic.type_name.endswith("WrenchStamped"):
        tq = msg.wrench.torque
        return convert.torque_msg(np.array([tq.x, tq.y, tq.z]), stamp, topic)
    if topic.type_name.endswith("TransformStamped"):
        r = msg.transform.rotation
        attitude = convert.quaternion_msg(np.array([r.x, r.y, r.z, r.w]), stamp, c.STATE_ATTITUDE)  # (its stamp and quaternion)
        return convert.transform_from_attitude(convert.transform_msg(topic), attitude)
    if topic is c.WHEEL_STATES:
        return convert.joint_state_msg(np.array(msg.velocity), np.array(msg.effort), stamp)
    if topic is c.STATE_WHEEL_SPEED:
        return convert.wheel_speed_msg(np.array(msg.velocity), stamp)
    if topic.type_name.endswith("MagneticField"):
        b = msg.magnetic_field
        variance = np.asarray(msg.magnetic_field_covariance)[[0, 4, 8]]
        return convert.magnetic_field_msg(np.array([b.x, b.y, b.z]), stamp, topic, variance)
    data = np.asarray(msg.data)
    if topic is c.CONTROLLER_DIAGNOSTICS:
        rows = data.reshape(len(c.DIAGNOSTICS_LAYOUT), 3)
        return convert.diagnostics_msg(float(rows[0, 0]), {label: rows[i] for i, label in enumerate(c.DIAGNOSTICS_LAYOUT) if i})
    if topic is c.ESTIMATOR_COVARIANCE:
        P = data[1:].reshape(6, 6)
        return convert.covariance_msg(float(data[0]), P if np.isfinite(P).all() else None)
    if topic is c.ESTIMATOR_DIAGNOSTICS:
        return convert.estimator_diagnostics_msg(data)
    if topic is c.CONTROL_DIPOLE:
        return convert.dipole_msg(float(data[0]), data[1:])
    raise AssertionError(f"no encoder for {topic.name}")


def _same(a: Any, b: Any, topic: c.Topic) -> bool:
    """Two messages equal, NaN equal to NaN (the float arrays' data compared as arrays; a "no
    data" sample by its header and :func:`~sappc_msgs_py.convert.is_no_data_msg`)."""
    if hasattr(a, "data") and hasattr(a, "layout"):
        return bool(a.layout == b.layout and np.array_equal(np.asarray(a.data), np.asarray(b.data), equal_nan=True))
    if convert.is_no_data_msg(b, topic):
        return bool(convert.is_no_data_msg(a, topic) and a.header == b.header)
    return bool(a == b)


def test_every_message_is_what_the_nodes_encoders_build(tmp_path: Path) -> None:
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message

    faults = [{"kind": "actuator_bias", "bias_Nm": [0.01, 0.0, 0.0], "start_s": 0.5}]
    for scenario in (_scenario("paper_tracking_orbit.yaml", 2.0), _scenario("paper_tracking.yaml", 1.0, faults=faults)):
        out = tmp_path / scenario.name
        _record_with_answers(scenario, out)
        by_name = {"/" + t.name.lstrip("/"): t for t in offline_topics(scenario)}
        seen: dict[str, int] = {}
        with next(out.glob("*.mcap")).open("rb") as f:
            for _, channel, message in make_reader(f).iter_messages():
                topic = by_name[channel.topic]
                k = seen[channel.topic] = seen.get(channel.topic, 0) + 1
                if k not in (1, 2, 150):  # the first (NaN rows before the controller's first step, no estimate), two later
                    continue
                msg = deserialize_message(message.data, topic.msg_class)
                assert _same(msg, _node_message(topic, msg, scenario), topic), (channel.topic, k)
                if topic.frame_id is not None and topic is not c.CLOCK:
                    assert msg.header.frame_id == topic.frame_id
        assert set(seen) == set(by_name)


def test_written_in_blocks_it_is_the_same_file_byte_for_byte(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """One call with the whole History, or its blocks cut anywhere (1, 7, 1000 samples; every 7),
    encoded a sample at a time or in pieces, in chunks of a few samples: the same MCAP file and
    ``metadata.yaml``, byte for byte."""
    scenario = _scenario("paper_tracking_orbit.yaml", 3.0)
    whole = simulate(scenario).history
    assert whole is not None
    monkeypatch.setattr(write_offline, "CHUNK_SIZE_BYTES", 20_000)  # a few samples a chunk: chunks cut across blocks and pieces
    files = []
    blockings: tuple[tuple[list[int], int], ...] = (([], write_offline.ENCODE_BYTES), ([1, 8, 1008], 1),
                                                    (list(range(7, 301, 7)), 50_000))
    for n, (cuts, encode_bytes) in enumerate(blockings):
        monkeypatch.setattr(write_offline, "ENCODE_BYTES", encode_bytes)  # 1: a piece of one sample
        out = tmp_path / str(n) / "bag"
        out.parent.mkdir()
        with OfflineBagWriter(scenario, out) as writer:
            bounds = [0, *[k for k in cuts if k < whole.t.size], whole.t.size]
            for lo, hi in itertools.pairwise(bounds):
                writer(whole.samples(lo, hi))
        files.append(((out / "bag_0.mcap").read_bytes(), (out / "metadata.yaml").read_text()))
    assert files[0] == files[1] == files[2]


def test_the_same_file_whatever_the_blocking_at_the_default_sizes(tmp_path: Path) -> None:
    scenario = _scenario("paper_tracking.yaml", 30.0)
    whole = simulate(scenario).history
    assert whole is not None
    files = []
    for n, step in enumerate((whole.t.size, 1000, 77)):
        out = tmp_path / str(n) / "bag"
        out.parent.mkdir()
        with OfflineBagWriter(scenario, out) as writer:
            for lo in range(0, whole.t.size, step):
                writer(whole.samples(lo, min(lo + step, whole.t.size)))
        files.append((out / "bag_0.mcap").read_bytes())
    assert files[0] == files[1] == files[2]


@pytest.mark.slow
def test_a_lockstep_graph_bag_has_the_same_topics_types_and_stamps(tracking_run: Any, tmp_path: Path) -> None:
    """Experiment 1 through ``sappc run`` (lockstep) and offline: the same topics, types, counts and
    stamps, the values within 1e-12 (the graph equals the offline runner to ~1e-16)."""
    from mcap.reader import make_reader

    out, _, _ = tracking_run
    scenario = load_scenario(SCENARIOS / "paper_tracking.yaml")
    _record(scenario, tmp_path / "bag")

    def channels(path: Path) -> dict[str, str]:
        with path.open("rb") as f:
            summary = make_reader(f).get_summary()
        assert summary is not None
        return {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}

    graph = channels(next((out / "bag").glob("*.mcap")))
    offline = channels(tmp_path / "bag" / "bag_0.mcap")
    assert offline == graph  # experiment 1's graph publishes nothing the record lacks
    g, o = read_bag(out / "bag"), read_bag(tmp_path / "bag")
    assert g.counts == o.counts
    for topic in graph:
        a, b = g.series[topic], o.series[topic]
        assert np.array_equal(a.stamps_ns, b.stamps_ns) and np.array_equal(a.log_time_ns, b.log_time_ns), topic
        values_a, values_b = a.values, b.values
        if topic == "/controller/diagnostics":  # the rejected count (27): not recorded offline; the answers (28:): the History's
            keep = np.r_[0:27] if np.isnan(values_b[:, 28:]).all() else np.r_[0:27, 28:36]
            values_a, values_b = values_a[:, keep], values_b[:, keep]
        assert np.allclose(values_a, values_b, rtol=0.0, atol=1e-12, equal_nan=True), topic
    meta_g = yaml.safe_load((out / "bag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    meta_o = yaml.safe_load((tmp_path / "bag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    for key in ("version", "storage_identifier", "duration", "starting_time", "message_count", "topics_with_message_count",
                "compression_format", "compression_mode", "ros_distro"):
        assert meta_g[key] == meta_o[key], key


def test_a_run_killed_midway_leaves_a_bag_that_repair_completes(tmp_path: Path) -> None:
    """The process ends without :meth:`close` (no summary, the last chunk lost): ``metadata.yaml``
    is there from the start, and :func:`~sappc.bag.rosbag2.repair` makes the chunks written
    readable, whole samples of every topic."""
    import subprocess
    import sys

    from sappc.bag.rosbag2 import repair

    code = ("import os, sys\n"
            "from sappc.scenario import read_scenario_mapping, scenario_from_mapping\n"
            "from sappc.offline.simulate import simulate\n"
            "from sappc.bag.write_offline import OfflineBagWriter\n"
            "raw = read_scenario_mapping(sys.argv[1]); raw['duration_s'] = 5.0\n"
            "scenario = scenario_from_mapping(raw)\n"
            "simulate(scenario, history='none', sinks=[OfflineBagWriter(scenario, sys.argv[2])])\n"
            "os._exit(0)\n")
    argv = [sys.executable, "-c", code, str(SCENARIOS / "paper_tracking.yaml"), str(tmp_path / "bag")]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "bag" / "metadata.yaml").exists()
    repair(tmp_path / "bag")
    counts = read_bag(tmp_path / "bag").counts
    assert len(set(counts.values())) == 1 and 0 < next(iter(counts.values())) < 501


def test_with_the_answers_sappc_rerun_reproduces_every_torque(tmp_path: Path) -> None:
    """``sappc rerun`` on an offline bag (the parameters embedded, the inputs paired by the stamps
    the diagnostics report): every computed torque bit for bit, the held and zero answers of a
    sensor dropout skipped."""
    import json
    import subprocess
    import sys

    scenario = _scenario("paper_tracking.yaml", 3.0, faults=[{"kind": "sensor_dropout", "start_s": 1.0, "end_s": 1.5}])
    answers = _record_with_answers(scenario, tmp_path / "bag")
    argv = [sys.executable, "-m", "sappc", "rerun", str(tmp_path / "bag"), "--json", "-"]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    doc = json.loads(proc.stdout)
    computed = int(np.count_nonzero(answers == c.ANSWER_COMMANDED))
    assert doc["all_identical"] and doc["identical"] == computed < answers.size

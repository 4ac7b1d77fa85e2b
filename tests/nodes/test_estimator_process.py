"""``python -m sappc_estimator`` as its own process, in lockstep between a publisher of the sensors
(this test: ``sensors/*``, ``state/attitude_epoch``) and the subscribers of its estimate (this test, and ``python -m sappc.graph.recorder``
as a second process): every sample answered, a clean stop on SIGINT (exit 0, its closing line,
timing and counts files, no shared-memory segment abandoned), and a bag whose estimator topics decode
with ``rosbags`` and with the project's reader into exactly what was received."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from sappc.bag.read import bag_estimate, read_bag
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import clock_msg, epoch_msg, gyro_msg, no_data_msg, ns_to_stamp, stamp_to_ns, star_tracker_msg

from conftest import ROOT
from shm_watch import ShmWatch
from test_estimator_node import DT_NS, EPOCHS, GYRO_VARIANCE, TRACKER_VARIANCE, measurements

pytestmark = pytest.mark.slow

#: Samples of the run; the one whose gyro sample is dropped (the injector's "no data").
N_SAMPLES, DROPPED = 40, 17
#: Longest wait for the processes to start (imports, the numba cache) and for each sample [s].
START_S, SAMPLE_S = 120.0, 30.0


def test_the_estimator_process_answers_every_sample_records_and_stops_cleanly(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    watch = ShmWatch().__enter__()  # the two processes' own shared memory (tests/shm_watch.py)
    env = dict(os.environ)  # the fixture set the domain, discovery range, Fast DDS profile and log directory
    bag_dir, timing, counts = tmp_path / "bag", tmp_path / "timing.json", tmp_path / "counts.json"
    rec = subprocess.Popen([sys.executable, "-m", "sappc.graph.recorder", "--ros-args", "-p", f"output_dir:={bag_dir}"],
                           env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=ROOT)
    watch.add(rec.pid)
    expected = json.dumps([f"{t.name}=2" for t in c.ESTIMATOR_TOPICS])  # this test and the recorder
    est = subprocess.Popen([sys.executable, "-m", "sappc_estimator", "--ros-args", "--params-file", str(ROOT / "config" / "estimator_mekf.yaml"),
                            "-p", f"timing_file:={timing}", "-p", f"counts_file:={counts}", "-p", f"expected_subscribers:={expected}"],
                           env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=ROOT)
    watch.add(est.pid)
    node = Node("state_publisher", context=ros_context)
    qos = c.qos_profile()
    pubs = {t.name: node.create_publisher(t.msg_class, t.name, qos) for t in (c.CLOCK, *c.ESTIMATOR_SUBSCRIPTIONS)}
    got: dict[str, dict[int, np.ndarray]] = {t.name: {} for t in (c.ESTIMATE_ATTITUDE, c.ESTIMATE_RATE, c.ESTIMATOR_COVARIANCE)}
    node.create_subscription(c.ESTIMATE_ATTITUDE.msg_class, c.ESTIMATE_ATTITUDE.name, lambda m: got[c.ESTIMATE_ATTITUDE.name].__setitem__(
        stamp_to_ns(m.header.stamp), np.array([m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w])), qos)
    node.create_subscription(c.ESTIMATE_RATE.msg_class, c.ESTIMATE_RATE.name, lambda m: got[c.ESTIMATE_RATE.name].__setitem__(
        stamp_to_ns(m.header.stamp), np.array([m.vector.x, m.vector.y, m.vector.z])), qos)
    node.create_subscription(c.ESTIMATOR_COVARIANCE.msg_class, c.ESTIMATOR_COVARIANCE.name, lambda m: got[c.ESTIMATOR_COVARIANCE.name].__setitem__(
        round(m.data[0] * 1e9), np.array(m.data[1:]).reshape(6, 6)), qos)
    for t in c.ESTIMATOR_TOPICS[2:]:
        if t is not c.ESTIMATOR_COVARIANCE:
            node.create_subscription(t.msg_class, t.name, lambda m: None, qos)  # the estimator waits for two subscribers on each
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)

    def spin_until(condition, what: str, seconds: float) -> None:  # type: ignore[no-untyped-def]
        deadline = time.monotonic() + seconds
        while not condition():
            assert time.monotonic() < deadline and est.poll() is None and rec.poll() is None, f"timed out waiting for {what}"
            ex.spin_once(timeout_sec=0.02)

    q, w = measurements(N_SAMPLES)
    try:
        spin_until(lambda: all(p.get_subscription_count() >= 2 for p in pubs.values()), "the estimator and the recorder", START_S)
        for k in range(N_SAMPLES):
            ns = k * DT_NS
            pubs[c.CLOCK.name].publish(clock_msg(ns / 1e9))
            if EPOCHS[ns] == ns:  # the tracker measured at this sample: its sample, stamped when measured
                pubs[c.SENSOR_STAR_TRACKER.name].publish(star_tracker_msg(q[k], TRACKER_VARIANCE, ns_to_stamp(ns), c.SENSOR_STAR_TRACKER))
            gyro = gyro_msg(w[k], GYRO_VARIANCE, ns_to_stamp(ns), c.SENSOR_GYRO)
            pubs[c.SENSOR_GYRO.name].publish(no_data_msg(c.SENSOR_GYRO, ns_to_stamp(ns)) if k == DROPPED else gyro)
            pubs[c.STATE_ATTITUDE_EPOCH.name].publish(epoch_msg(EPOCHS[ns], ns_to_stamp(ns), c.STATE_ATTITUDE_EPOCH))
            spin_until(lambda: all(ns in v for v in got.values()), f"the estimate of {ns} ns", SAMPLE_S)
        assert all(p.wait_for_all_acked() for p in pubs.values())
    finally:
        est.send_signal(signal.SIGINT)
        log = est.communicate(timeout=60)[0].decode()
        rec.send_signal(signal.SIGINT)
        rec_log = rec.communicate(timeout=60)[0].decode()
        ex.shutdown()
        node.destroy_node()
        watch.__exit__(None, None, None)
    watch.assert_clean()  # both exited; no shared memory of theirs left behind
    assert est.returncode == 0, log
    assert rec.returncode == 0, rec_log
    assert (f"finished: {N_SAMPLES} samples, {N_SAMPLES - 1} filter steps (3 updates, 0 gate rejections, 0 re-initialisations, "
            "0 recoveries), 1 no-data samples (0 withheld)") in log, log  # tracker at 0 (initialises: its epoch is its stamp), 10, 20, 30
    stats = json.loads(timing.read_text())
    assert stats["samples"] == N_SAMPLES and stats["no_data_samples"] == 1  # the dropped gyro sample: "no data", not rejected
    assert stats["no_data_inputs"] == 1 and stats["rejected"] == 0 and stats["future_tracker_epochs"] == 0
    # the health: at t = 0 (OK), at the dropped sample (a warning: no estimate) and at the next (OK again)
    per_sample = [t for t in c.ESTIMATOR_TOPICS if t is not c.ESTIMATOR_HEALTH]
    assert json.loads(counts.read_text()) == {**{"/" + t.name: N_SAMPLES for t in per_sample}, "/" + c.ESTIMATOR_HEALTH.name: 3}
    assert np.all(np.isnan(got[c.ESTIMATE_ATTITUDE.name][DROPPED * DT_NS])) and np.all(np.isfinite(got[c.ESTIMATE_ATTITUDE.name][0]))

    # the bag: every estimator topic recorded, decoded by rosbags and by the project's reader alike
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    recorded: dict[str, int] = {}
    with AnyReader([bag_dir], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, log_ns, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            recorded[conn.topic] = recorded.get(conn.topic, 0) + 1
            if conn.topic == "/" + c.ESTIMATOR_COVARIANCE.name:
                assert log_ns == round(msg.data[0] * 1e9)  # the recorder stamps it by data[0] (simulated time)
    assert all(recorded["/" + t.name] == N_SAMPLES for t in per_sample) and recorded["/" + c.ESTIMATOR_HEALTH.name] == 3, recorded
    estimate = bag_estimate(read_bag(bag_dir))
    assert estimate is not None and estimate.stamps_ns.tolist() == [k * DT_NS for k in range(N_SAMPLES)]
    for k, ns in enumerate(estimate.stamps_ns.tolist()):
        np.testing.assert_array_equal(estimate.q_BN[k], got[c.ESTIMATE_ATTITUDE.name][ns])
        np.testing.assert_array_equal(estimate.omega_BN_B[k], got[c.ESTIMATE_RATE.name][ns])
        np.testing.assert_array_equal(estimate.covariance[k], got[c.ESTIMATOR_COVARIANCE.name][ns])
    assert estimate.diagnostics["status"][DROPPED] == c.ESTIMATOR_NO_INPUT and estimate.diagnostics["updates"][-1] == 3
    assert np.all(np.isfinite(estimate.attitude_sigma_rad[estimate.diagnostics["status"] != c.ESTIMATOR_NO_INPUT]))


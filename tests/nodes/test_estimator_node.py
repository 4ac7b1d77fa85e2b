"""The estimator node (``python -m sappc_estimator``) in-process on an isolated domain, driven by
messages: lockstep estimates equal the kernel called directly on the same measurements, bit for
bit; invalid inputs give the "no data" estimate and are counted by reason; stamps in the past or
far ahead are rejected; a filter driven non-finite starts afresh; real time steps once per fresh
state pair; the controller takes the estimate by a remap and answers a "no data" sample as its
own dropped input; bad parameters name themselves; the flight parameters file is what ``sappc
params --estimator`` writes.  Waits are on conditions (with a generous deadline), never on fixed
sleeps.  The multi-process run (and its bag) is in ``test_estimator_process.py``."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from typing import Any

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from gnc_common.attitude import quat_multiply, rotation_vector_to_quaternion
from gnc_common.validation import ConfigError
from sappc_estimator.core import mekf
from sappc_estimator.core.config import MekfConfig
from sappc_estimator.params import config_from_parameters, parameters_from_config
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import (
    clock_msg,
    covariance_from_msg,
    diagnostics_from_msg,
    epoch_msg,
    gyro_msg,
    estimator_diagnostics_from_msg,
    ns_to_stamp,
    quaternion_msg,
    stamp_to_ns,
    star_tracker_msg,
    torque_from_msg,
    vector3_msg,
)
from spacecraft_sim.core.sensors import S_BIAS0, Gyro, Sensors, StarTracker, measure

from conftest import ROOT, SCENARIOS
from fake_clock import FakeClock
from test_nodes import DEADLINE_S, Q0, _controller_overrides

#: The control period of the sequences [ns] (100 Hz); the tracker updates every 10th sample.
DT_NS = 10_000_000
#: A slowly rotating truth: constant body rate [rad/s].
OMEGA_TRUE = np.array([1.0e-3, -2.0e-3, 0.5e-3])
#: The flight scenario's sensors (config/scenarios/paper_tracking_flight.yaml): a 10 Hz tracker,
#: a fibre-optic gyro with a residual bias.
SENSORS = Sensors(star_tracker=StarTracker(noise_rad=(9.7e-6, 9.7e-6, 7.3e-5), rate_hz=10.0),
                  gyro=Gyro(angle_random_walk_rad_sqrt_s=1.45e-6, bias_random_walk_rad_s_sqrt_s=8.1e-10, initial_bias_rad_s=(2.4e-6, -1.5e-6, 1.0e-6)),
                  seed=7)
#: The filter for those sensors (what ``estimator: {kind: mekf}`` gives).
CONFIG = MekfConfig(tracker_noise_rad=(9.7e-6, 9.7e-6, 7.3e-5), gyro_angle_random_walk_rad_sqrt_s=1.45e-6,
                    gyro_bias_random_walk_rad_s_sqrt_s=8.1e-10)
NO_DATA_Q = (math.nan,) * 4
NO_DATA_W = (math.nan,) * 3
#: What the sensors' messages say of their noise (what a plant's data sheet gives; the filter's own
#: figures are its parameters).
GYRO_VARIANCE, TRACKER_VARIANCE = (1e-8, 1e-8, 1e-8), (9.4e-11, 9.4e-11, 5.3e-9)


#: The epochs [ns] of the last :func:`measurements` (the tracker's own time of each held quaternion).
EPOCHS: dict[int, int] = {}


def measurements(n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` samples of the sensors (``spacecraft_sim.core.sensors.measure``, the plant's kernel)
    on the rotating truth: the tracker's quaternion (held between its 10 Hz updates) (n, 4), the
    gyro's rate (n, 3); the epoch of sample ``k``'s quaternion [ns] in :data:`EPOCHS` (what
    :meth:`Driver.send` publishes by default)."""
    prm, draws, outages = SENSORS.params(DT_NS / 1e9), SENSORS.draws(n), SENSORS.outages()
    held, bias, y = np.zeros(5), prm[S_BIAS0 : S_BIAS0 + 3].copy(), np.empty(mekf.N_MEAS)
    q, w = np.empty((n, 4)), np.empty((n, 3))
    EPOCHS.clear()
    for k in range(n):
        t = k * DT_NS / 1e9
        q_true = quat_multiply(np.asarray(Q0), rotation_vector_to_quaternion(OMEGA_TRUE * t))
        measure(k, t, float(k * DT_NS), q_true, OMEGA_TRUE, draws[k], prm, outages, held, bias, y)
        q[k], w[k] = y[:4], y[4:7]
        EPOCHS[k * DT_NS] = int(y[7])
    return q, w


def overrides(config: MekfConfig = CONFIG, **extra: Any) -> list[Parameter]:
    values = {**parameters_from_config(config), **extra}
    return [Parameter(k, value=v) for k, v in values.items()]


def _quaternion(m: Any) -> np.ndarray:
    return np.array([m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w])


def _vector(m: Any) -> np.ndarray:
    return np.array([m.vector.x, m.vector.y, m.vector.z])


class Driver:
    """A test node publishing the estimator's inputs (and /clock) and collecting every output by stamp."""

    def __init__(self, context: Any, nodes: list[Any], extra_topics: tuple[c.Topic, ...] = ()) -> None:
        self.node = Node("driver", context=context)
        qos = c.qos_profile()
        self.pub = {t.name: self.node.create_publisher(t.msg_class, t.name, qos)
                    for t in (*c.ESTIMATOR_SUBSCRIPTIONS, c.CLOCK, *extra_topics)}
        self.got: dict[str, dict[int, Any]] = {t.name: {} for t in c.ESTIMATOR_TOPICS if t is not c.ESTIMATOR_HEALTH}  # per sample
        self.health: list[Any] = []  # diagnostics, as published (not per sample)
        self.node.create_subscription(c.ESTIMATOR_HEALTH.msg_class, c.ESTIMATOR_HEALTH.name, self.health.append, qos)
        decoders = {c.ESTIMATE_ATTITUDE.name: _quaternion, c.ESTIMATOR_COVARIANCE.name: covariance_from_msg,
                    c.ESTIMATOR_DIAGNOSTICS.name: estimator_diagnostics_from_msg}
        for t in c.ESTIMATOR_TOPICS:
            if t is c.ESTIMATOR_HEALTH:
                continue
            decode = decoders.get(t.name, _vector)
            header_free = t.type_name == "std_msgs/msg/Float64MultiArray"  # stamped by data[0], the contract's rule
            stamp = (lambda m: round(m.data[0] * 1e9)) if header_free else (lambda m: stamp_to_ns(m.header.stamp))
            self.node.create_subscription(t.msg_class, t.name, lambda m, d=decode, s=stamp, n=t.name: self.got[n].__setitem__(s(m), d(m)), qos)
        self.executor = SingleThreadedExecutor(context=context)
        for n in (self.node, *nodes):
            self.executor.add_node(n)

    def spin_until(self, condition: Any, what: str) -> None:
        deadline = time.monotonic() + DEADLINE_S
        while not condition():
            assert time.monotonic() < deadline, f"timed out waiting for {what}"
            self.executor.spin_once(timeout_sec=0.02)

    def matched(self, estimator: Any) -> None:
        """Until the estimator's subscriptions and every one of its publishers are matched with this node."""
        self.spin_until(lambda: all(self.pub[t.name].get_subscription_count() >= 1 for t in c.ESTIMATOR_SUBSCRIPTIONS)
                        and all(p.pub.get_subscription_count() >= 1 for p in estimator.pub.values()), "the estimator's topics matched")

    def send(self, ns: int, q: Any, w: Any, *, frame: str | None = None, topics: tuple[c.Topic, ...] = c.ESTIMATOR_SUBSCRIPTIONS,
             epoch_ns: int | None = None) -> None:
        """Publish the sensors of stamp ``ns`` as a plant does (raw fields: the encoders refuse the
        bad values the tests send): the gyro's ``w`` (its frame id ``frame`` when given), the
        tracker's epoch (``epoch_ns``, else :data:`EPOCHS`' of ``ns``, else ``ns``), and the
        tracker's sample ``q`` stamped with that epoch when the tracker measured it at this stamp
        (epoch ``ns``: a held sample is not sent again)."""
        epoch_ns = EPOCHS.get(ns, ns) if epoch_ns is None else epoch_ns
        gyro = gyro_msg([0.0, 0.0, 0.0], GYRO_VARIANCE, ns_to_stamp(ns), c.SENSOR_GYRO)
        gyro.angular_velocity.x, gyro.angular_velocity.y, gyro.angular_velocity.z = (float(v) for v in w)
        if frame is not None:
            gyro.header.frame_id = frame
        tracker = star_tracker_msg(Q0, TRACKER_VARIANCE, ns_to_stamp(epoch_ns), c.SENSOR_STAR_TRACKER)
        tracker.orientation.x, tracker.orientation.y, tracker.orientation.z, tracker.orientation.w = (float(v) for v in q)
        epoch = epoch_msg(epoch_ns, ns_to_stamp(ns), c.STATE_ATTITUDE_EPOCH)
        messages = ((c.SENSOR_STAR_TRACKER, tracker if epoch_ns == ns else None), (c.SENSOR_GYRO, gyro), (c.STATE_ATTITUDE_EPOCH, epoch))
        for topic, msg in messages:
            if topic in topics and msg is not None:
                self.pub[topic.name].publish(msg)

    def answered(self, ns: int) -> bool:
        return all(ns in v for v in self.got.values())

    def sample(self, ns: int, q: Any, w: Any, **kw: Any) -> None:
        """Send the state of ``ns`` and wait for every output of that stamp (lockstep, as a plant)."""
        self.send(ns, q, w, **kw)
        self.spin_until(lambda: self.answered(ns), f"the outputs of {ns} ns")

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


@pytest.fixture
def estimator(ros_context):  # type: ignore[no-untyped-def]
    from sappc_estimator.node import EstimatorNode

    node = EstimatorNode(context=ros_context, parameter_overrides=overrides())
    driver = Driver(ros_context, [node])
    driver.matched(node)
    yield node, driver
    driver.close()
    node.destroy_node()


class Reference:
    """The kernel called directly (``mekf_step`` on arrays of its own), the node's reference."""

    def __init__(self, config: MekfConfig = CONFIG) -> None:
        self.prm, self.st, self.P = config.params(), mekf.new_state(), np.zeros((6, 6))
        self.work, self.out, self.y = np.zeros((mekf.N_EST_WORK, 6)), np.empty(mekf.N_EST_OUT), np.empty(mekf.N_MEAS)

    def step(self, t_s: float, q: np.ndarray, w: np.ndarray, epoch_s: float | None = None) -> int:
        """A step with the tracker's epoch ``epoch_s`` (``None``: :data:`EPOCHS`' of ``t_s``)."""
        self.y[:4], self.y[4:7] = q, w
        self.y[7] = EPOCHS[round(t_s * 1e9)] / 1e9 if epoch_s is None else epoch_s
        return int(mekf.mekf_step(self.prm, t_s, self.y, self.st, self.P, self.work, self.out))


def _assert_no_data(drv: Driver, ns: int) -> None:
    """Every estimate topic of stamp ``ns`` is NaN in every value (the contract's "no data")."""
    assert np.all(np.isnan(drv.got[c.ESTIMATE_ATTITUDE.name][ns]))
    for t in (c.ESTIMATE_RATE, c.ESTIMATOR_GYRO_BIAS, c.ESTIMATOR_ATTITUDE_SIGMA, c.ESTIMATOR_BIAS_SIGMA):
        assert np.all(np.isnan(drv.got[t.name][ns])), t.name
    t_s, P = drv.got[c.ESTIMATOR_COVARIANCE.name][ns]
    assert t_s == ns / 1e9 and np.all(np.isnan(P))


def test_lockstep_estimates_equal_the_kernel_called_directly_bit_for_bit(estimator) -> None:  # type: ignore[no-untyped-def]
    """A 10 Hz tracker held at 100 Hz and a biased gyro on a slowly rotating truth, fed sample by
    sample as messages (the tracker's own samples at 10 Hz, stamped when measured): every output
    equals ``mekf_step`` called on the same arrays (the tracker held at 100 Hz) at ``t = stamp``
    [s], bit for bit.  Samples 25 and 26 arrive without data (the injector's NaN gyro sample, counted
    as an input without data, not a rejected message; a gyro sample with a wrong frame id, rejected):
    "no data" at their stamps, and the kernel skips them (sample 27 propagates over 30 ms)."""
    node, drv = estimator
    q, w = measurements(60)
    skipped = {25: dict(w=NO_DATA_W), 26: dict(frame="inertial")}
    ref = Reference()
    for k in range(60):
        ns = k * DT_NS
        bad = skipped.get(k, {})
        drv.sample(ns, q[k], bad.get("w", w[k]), frame=bad.get("frame"))
        diag = drv.got[c.ESTIMATOR_DIAGNOSTICS.name][ns]
        if k in skipped:
            _assert_no_data(drv, ns)
            assert diag["status"] == c.ESTIMATOR_NO_INPUT
            continue
        status = ref.step(ns / 1e9, q[k], w[k])
        assert diag["status"] == status and diag["time_s"] == ns / 1e9
        np.testing.assert_array_equal(drv.got[c.ESTIMATE_ATTITUDE.name][ns], ref.out[mekf.EO_Q : mekf.EO_Q + 4])
        np.testing.assert_array_equal(drv.got[c.ESTIMATE_RATE.name][ns], ref.out[mekf.EO_OMEGA : mekf.EO_OMEGA + 3])
        np.testing.assert_array_equal(drv.got[c.ESTIMATOR_GYRO_BIAS.name][ns], ref.out[mekf.EO_B : mekf.EO_B + 3])
        np.testing.assert_array_equal(drv.got[c.ESTIMATOR_ATTITUDE_SIGMA.name][ns], ref.out[mekf.EO_SIGMA : mekf.EO_SIGMA + 3])
        np.testing.assert_array_equal(drv.got[c.ESTIMATOR_BIAS_SIGMA.name][ns], ref.out[mekf.EO_SIGMA + 3 : mekf.EO_SIGMA + 6])
        np.testing.assert_array_equal(drv.got[c.ESTIMATOR_COVARIANCE.name][ns][1], ref.P)
        np.testing.assert_array_equal([diag["nis"], diag["updates"], diag["gate_rejections"], diag["reinitialisations"]],
                                      [ref.st[mekf.ES_NIS], ref.st[mekf.ES_N_UPD], ref.st[mekf.ES_N_REJ], ref.st[mekf.ES_N_REINIT]])
    # sample 0 (measured at its own stamp: its epoch) initialises the estimate, 10 .. 50 update
    assert ref.st[mekf.ES_N_UPD] == 5
    statuses = [drv.got[c.ESTIMATOR_DIAGNOSTICS.name][k * DT_NS]["status"] for k in range(60)]
    assert statuses[0] == mekf.STATUS_INITIALISED and statuses[10] == statuses[20] == mekf.STATUS_UPDATED
    assert statuses[11] == mekf.STATUS_PROPAGATED
    last = drv.got[c.ESTIMATOR_DIAGNOSTICS.name][59 * DT_NS]
    assert (last["no_data_samples"], last["rejected_messages"], last["withheld_samples"], last["monitor_level"]) == (2, 1, 0, mekf.MON_OK)
    assert node.statistics() == {"samples": 60, "steps": 58, "updates": 5, "gate_rejections": 0, "reinitialisations": 0, "recoveries": 0,
                                 "withheld_samples": 0, "no_data_samples": 2,
                                 "rejected": 1, "rejected_by_reason": {"invalid": 1, "stamp_in_past": 0, "stamp_too_far_ahead": 0},
                                 "no_data_inputs": 1, "future_tracker_epochs": 0}
    # the estimate is the filter's, not the tracker's sample: between updates it moves with the gyro
    assert not np.array_equal(drv.got[c.ESTIMATE_ATTITUDE.name][15 * DT_NS], q[15])


def test_the_health_goes_out_on_diagnostics_as_ros_reports_health(estimator) -> None:  # type: ignore[no-untyped-def]
    """``diagnostics`` (``diagnostic_msgs/DiagnosticArray``): one status named
    ``contract.ESTIMATOR_HEALTH_NAME`` whose level is the monitor's (0 OK here: a consistent run), its
    figures as the key/values of ``contract.ESTIMATOR_HEALTH_KEYS`` (the window, the NIS sum's band
    at its stated probability: chi-square with 3 x 20 degrees of freedom), published when the level
    changes and once a second of the samples' time (so 3 reports over 2.5 s here), stamped with
    the sample."""
    from scipy.stats import chi2

    node, drv = estimator
    q, w = measurements(251)
    for k in range(251):
        drv.sample(k * DT_NS, q[k], w[k])
    drv.spin_until(lambda: len(drv.health) == 3, "three health reports")
    stamps = [stamp_to_ns(m.header.stamp) for m in drv.health]
    assert stamps == [0, 1_000_000_000, 2_000_000_000]
    last = drv.health[-1].status
    assert len(last) == 1 and last[0].name == c.ESTIMATOR_HEALTH_NAME and last[0].level == b"\x00"  # OK
    values = {kv.key: kv.value for kv in last[0].values}
    assert tuple(values) == c.ESTIMATOR_HEALTH_KEYS
    from sappc_estimator.core.config import DEFAULT_MONITOR_ERROR_PROBABILITY as P_ERROR  # the default error band, two-sided

    lo, hi = chi2.ppf((1.0 - P_ERROR) / 2.0, 60), chi2.isf((1.0 - P_ERROR) / 2.0, 60)
    assert values["window_samples"] == "20" and values["nis_sum_dof"] == "60" and values["estimate"] == "used"
    assert values["outside_in_a_row"] == "0" and values["persistence"] == "2"  # in the band: none outside; the default persistence
    assert values["nis_sum_band"] == f"[{lo:.6g}, {hi:.6g}]" and values["band_probability"] == f"{P_ERROR:.6g}"
    assert lo < float(values["nis_sum"]) < hi  # the window of 20 tracker samples at 2 s: a verdict
    # the drift test (issue 46): its CUSUM below its threshold (h_d = 25.9 sigmas at the default 1e-6 false alarms a sample,
    # docs/estimator.md), no alarm
    assert float(values["drift_threshold"]) == pytest.approx(25.9, abs=0.05) and values["drift_alarms"] == "0"
    assert 0.0 <= float(values["drift_statistic"]) < float(values["drift_threshold"])
    # the words: no verdict while the window of 20 tracker samples (2 s at 10 Hz) fills, then the monitor's level
    assert [m.status[0].message for m in drv.health] == ["no verdict yet: the innovations' window is filling"] * 2 + [
        "consistent: the innovations' window inside its band"]


def test_an_estimate_the_filter_has_not_confirmed_is_withheld_as_no_data(ros_context) -> None:  # type: ignore[no-untyped-def]
    """A prior 90 deg off with a 0.2 rad sigma: the tracker's samples fail the gate; until a tracker
    sample is accepted the node publishes "no data" on ``estimate/*`` (the controller's inputs: it
    answers as to a dropped input, zero torque before any valid state) while the filter's own
    figures (bias, sigmas, covariance) go out; the withheld samples are counted, and the health is a
    warning saying so."""
    from sappc_estimator.node import EstimatorNode

    prior = quat_multiply(np.asarray(Q0), rotation_vector_to_quaternion(np.array([1.0, -2.0, 2.0]) / 3.0 * np.pi / 2.0))
    config = MekfConfig(tracker_noise_rad=(9.7e-6, 9.7e-6, 7.3e-5), gyro_angle_random_walk_rad_sqrt_s=1.45e-6,
                        gyro_bias_random_walk_rad_s_sqrt_s=8.1e-10, initial_q_BN=tuple(prior), initial_attitude_sigma_rad=0.2)
    node = EstimatorNode(context=ros_context, parameter_overrides=overrides(config))
    drv = Driver(ros_context, [node])
    try:
        drv.matched(node)
        q, w = measurements(12)
        for k in range(12):
            drv.sample(k * DT_NS, q[k], w[k])
        for k in range(12):
            assert np.all(np.isnan(drv.got[c.ESTIMATE_ATTITUDE.name][k * DT_NS])) and np.all(np.isnan(drv.got[c.ESTIMATE_RATE.name][k * DT_NS]))
            assert np.all(np.isfinite(drv.got[c.ESTIMATOR_GYRO_BIAS.name][k * DT_NS]))
        diag = drv.got[c.ESTIMATOR_DIAGNOSTICS.name][11 * DT_NS]
        assert diag["gate_rejections"] == 2 and diag["withheld_samples"] == 12 and node.withheld == 12 and node.rejected == 0
        drv.spin_until(lambda: len(drv.health) >= 1, "a health report")
        status = drv.health[0].status[0]
        assert status.level == b"\x01" and status.message == ("no verdict yet: the innovations' window is filling; the estimate is withheld "
                                                             "(a prior, or re-initialised, not yet confirmed by a tracker sample)")
        assert {kv.key: kv.value for kv in status.values}["estimate"] == "withheld"
    finally:
        drv.close()
        node.destroy_node()


def test_before_any_estimate_the_health_warns_that_there_is_none(estimator) -> None:  # type: ignore[no-untyped-def]
    """A first sample without a valid input: no figures; the health is a warning that says so."""
    node, drv = estimator
    q, _ = measurements(1)
    drv.sample(0, q[0], NO_DATA_W)
    drv.spin_until(lambda: len(drv.health) >= 1, "a health report")
    status = drv.health[0].status[0]
    assert status.level == b"\x01" and status.message == "no estimate: initialising or no valid input"


def test_the_statistics_go_to_the_timing_file_when_one_is_named_and_nowhere_else(ros_context, tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    from sappc_estimator.node import EstimatorNode

    monkeypatch.chdir(tmp_path)
    for timing in ("", str(tmp_path / "timing.json")):
        node = EstimatorNode(context=ros_context, parameter_overrides=overrides(timing_file=timing))
        try:
            node.finish()
            expected = node.statistics()
        finally:
            node.destroy_node()
        written = sorted(p.name for p in tmp_path.iterdir() if p.is_file())
        if timing:
            assert written == ["timing.json"] and json.loads((tmp_path / "timing.json").read_text()) == json.loads(json.dumps(expected))
        else:
            assert written == []  # no file named: none written


def test_the_node_waits_for_a_reader_of_its_loop_outputs_only_and_lists_its_parameter_groups(ros_context) -> None:  # type: ignore[no-untyped-def]
    """The start gate: the estimate (what the controller reads) must have a subscriber before the
    node answers; its diagnostics and the filter's figures need none.  The parameter groups are a
    class's (``--help`` and the node reference list them without a node)."""
    from sappc_estimator.node import COMMON_PARAMETERS, FILTER_PARAMETERS, EstimatorNode, _LOOP_OUTPUTS

    sections = EstimatorNode.parameter_sections()
    assert [ps for _, ps in sections] == [EstimatorNode.PARAMETERS, FILTER_PARAMETERS, COMMON_PARAMETERS]
    node = EstimatorNode(context=ros_context, parameter_overrides=overrides())
    try:
        waits = {name: p.min_subscribers for name, p in node.pub.items()}
    finally:
        node.destroy_node()
    assert {n for n, k in waits.items() if k == 1} == {t.name for t in _LOOP_OUTPUTS} and set(waits.values()) == {0, 1}


def test_tracker_samples_keep_at_most_their_bound_and_name_the_epoch_the_filter_may_use() -> None:
    """:class:`TrackerSamples` by itself: the bound on the samples kept (the oldest dropped), the
    quaternion before any valid sample (four NaN: no measurement), an epoch named before its sample
    arrived (real time: the latest valid one's, no new measurement), an old epoch named again (a
    frozen tracker: itself, not new to the filter), an invalid first sample (its own epoch, no
    quaternion)."""
    from sappc_estimator.node import TrackerSamples

    q1, q2 = np.array([0.0, 0.0, 0.0, 1.0]), np.array([0.0, 0.0, 0.6, 0.8])
    kept = TrackerSamples()
    for k in range(TrackerSamples.MAX_KEPT + 1):
        kept.add(k, q1)
    assert not kept.ready(0) and kept.ready(1) and kept.ready(TrackerSamples.MAX_KEPT)  # the oldest dropped, the rest kept

    ts = TrackerSamples()
    assert ts.q.shape == (4,) and np.all(np.isnan(ts.q))
    assert ts.use(5) == 5 and np.all(np.isnan(ts.q))  # before any sample: its own epoch, no quaternion
    ts.add(10, None)  # arrived invalid
    assert ts.use(10) == 10 and ts.q_ns is None and np.all(np.isnan(ts.q))
    ts.add(20, q1)
    assert ts.use(20) == 20 and np.array_equal(ts.q, q1)
    assert ts.use(30) == 20 and np.array_equal(ts.q, q1)  # 30 not arrived: the latest valid one's epoch
    ts.add(30, q2)
    assert ts.use(30) == 30 and np.array_equal(ts.q, q2)
    assert ts.use(20) == 20 and ts.q_ns == 30  # an old epoch named again: itself (not new), the latest quaternion kept


BAD = {
    "NaN in the gyro's sample (the injector's no data)": dict(w=NO_DATA_W),
    "Inf in the rate": dict(w=(math.inf, 0.0, 0.0)),
    "a wrong frame id": dict(frame="inertial"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_an_invalid_input_gives_the_no_data_estimate_at_its_stamp_and_is_counted(estimator, case) -> None:  # type: ignore[no-untyped-def]
    """Lockstep: the sample completes (the controller downstream answers it at once), its estimate
    is "no data", the input is counted as invalid (the injector's "no data", NaN in every value: as
    an input without data, not a rejected message); the filter did not step, and the next valid
    sample propagates from the last valid one."""
    node, drv = estimator
    q, w = measurements(3)
    drv.sample(0, q[0], w[0])
    kwargs: dict[str, Any] = dict(q=q[1], w=w[1])
    kwargs.update(BAD[case])
    drv.sample(DT_NS, **kwargs)
    _assert_no_data(drv, DT_NS)
    assert drv.got[c.ESTIMATOR_DIAGNOSTICS.name][DT_NS]["status"] == c.ESTIMATOR_NO_INPUT
    no_data = BAD[case].get("w") is NO_DATA_W
    assert node.rejected_by_reason == ({} if no_data else {"invalid": 1}) and node.no_data_inputs == int(no_data)
    assert node.steps == 1 and node.no_data == 1
    drv.sample(2 * DT_NS, q[2], w[2])
    ref = Reference()
    ref.step(0.0, q[0], w[0])
    assert ref.step(2 * DT_NS / 1e9, q[2], w[2]) == mekf.STATUS_PROPAGATED  # over 20 ms
    np.testing.assert_array_equal(drv.got[c.ESTIMATE_ATTITUDE.name][2 * DT_NS], ref.out[:4])
    assert drv.got[c.ESTIMATOR_DIAGNOSTICS.name][2 * DT_NS]["rejected_messages"] == int(not no_data)


def test_stamps_in_the_past_or_too_far_ahead_are_rejected_and_counted_by_reason(estimator) -> None:  # type: ignore[no-untyped-def]
    """Lockstep: a stamp not after the last answered sample is "in the past" (the same stamp again:
    its three inputs rejected; 1 ns later: answered); more than max_stamp_ahead_s (1 s) after the latest /clock is
    "too far ahead" (exactly 1 s: answered)."""
    node, drv = estimator
    q, w = measurements(1)
    drv.sample(DT_NS, q[0], w[0])
    drv.send(DT_NS, q[0], w[0])  # the stamp just answered: the three inputs rejected (the tracker's: not after its last)
    drv.spin_until(lambda: node.rejected == 3, "three past stamps rejected")
    drv.sample(DT_NS + 1, q[0], w[0])
    drv.pub[c.CLOCK.name].publish(clock_msg(1.0))
    drv.spin_until(lambda: node._clock_ns == 1_000_000_000, "/clock 1 s")
    drv.send(2_000_000_001, q[0], w[0])  # 1 s + 1 ns ahead: rejected
    drv.spin_until(lambda: node.rejected == 6, "three far-ahead stamps rejected")
    drv.sample(2_000_000_000, q[0], w[0])  # exactly 1 s ahead
    assert node.rejected_by_reason == {"stamp_in_past": 3, "stamp_too_far_ahead": 3}
    assert node.samples == 3 and node.no_data == 0
    assert drv.got[c.ESTIMATOR_DIAGNOSTICS.name][2_000_000_000]["rejected_messages"] == 6


def test_an_implausible_rate_is_no_data_and_leaves_the_filter_as_it_was(estimator) -> None:  # type: ignore[no-untyped-def]
    """A finite but absurd rate (1e300 rad/s) passes the message checks; the filter takes it as no
    measurement (docs/estimator.md, step 0): that sample is "no data" and the filter continues from
    where it was, exactly as if the sample had never come (the offline loop answers it the same way)."""
    node, drv = estimator
    q, w = measurements(23)
    for k in range(21):  # initialised at 0, updated at 10 and 20
        drv.sample(k * DT_NS, q[k], w[k])
    assert node.filter.updates == 2
    before = node.filter.st.copy(), node.filter.P.copy()
    drv.sample(21 * DT_NS, q[21], (1e300, 0.0, 0.0))
    _assert_no_data(drv, 21 * DT_NS)
    assert node.rejected == 0 and node.no_data == 1
    np.testing.assert_array_equal(node.filter.st, before[0])
    np.testing.assert_array_equal(node.filter.P, before[1])
    drv.sample(22 * DT_NS, q[22], w[22])
    assert drv.got[c.ESTIMATOR_DIAGNOSTICS.name][22 * DT_NS]["status"] == mekf.STATUS_PROPAGATED
    assert node.filter.updates == 2



def test_realtime_steps_once_per_fresh_state_pair_with_its_stamp(ros_context, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Real time: a step as soon as the gyro and the epoch of a new stamp have arrived (either
    order), stamped with it, at the filter time counted from the first sample; half a pair, a
    repeated stamp (rejected per topic) or an invalid input make no step; latency is measured."""
    from sappc_estimator.node import EstimatorNode

    node = EstimatorNode(context=ros_context, parameter_overrides=overrides(mode="realtime"))
    t0 = 1_795_000_000 * 1_000_000_000  # epoch stamps, as on a real-time graph
    clock = FakeClock(t0)
    monkeypatch.setattr(node, "get_clock", lambda: clock)
    drv = Driver(ros_context, [node])
    try:
        drv.matched(node)
        q, w = measurements(3)
        ref = Reference()
        att, rate = (c.STATE_ATTITUDE_EPOCH, c.SENSOR_STAR_TRACKER), (c.SENSOR_GYRO,)  # the epoch and the tracker's sample; the gyro
        clock.ns = t0 + 400_000  # 0.4 ms after the state's stamp
        drv.send(t0, q[0], w[0], topics=att, epoch_ns=t0 + EPOCHS[0 * DT_NS])
        drv.spin_until(lambda: node._rt.last_ns(c.STATE_ATTITUDE_EPOCH.name) == t0, "half a pair")
        assert node.steps == 0
        drv.send(t0, q[0], w[0], topics=rate, epoch_ns=t0 + EPOCHS[0 * DT_NS])
        drv.spin_until(lambda: drv.answered(t0), "the estimate of the first pair")
        ref.step(0.0, q[0], w[0])
        drv.send(t0, q[0], w[0], topics=att[:1], epoch_ns=t0 + EPOCHS[0 * DT_NS])  # the same stamp again on one topic: in the past
        drv.spin_until(lambda: node.rejected == 1, "a repeated stamp rejected")
        drv.send(t0 + DT_NS, q[1], (math.nan, 0.0, 0.0), topics=rate, epoch_ns=t0 + EPOCHS[1 * DT_NS])  # invalid: no sample
        drv.send(t0 + DT_NS, q[1], w[1], topics=att, epoch_ns=t0 + EPOCHS[1 * DT_NS])
        drv.spin_until(lambda: node.rejected == 2 and node._rt.last_ns(c.STATE_ATTITUDE_EPOCH.name) == t0 + DT_NS, "frame 1's inputs")
        clock.ns = t0 + 2 * DT_NS + 11_000_000  # frame 2 answered 11 ms late: a late step
        drv.send(t0 + 2 * DT_NS, q[2], w[2], topics=rate, epoch_ns=t0 + EPOCHS[2 * DT_NS])  # rate first
        drv.send(t0 + 2 * DT_NS, q[2], w[2], topics=att, epoch_ns=t0 + EPOCHS[2 * DT_NS])
        drv.spin_until(lambda: drv.answered(t0 + 2 * DT_NS), "the estimate of frame 2")
        ref.step(2 * DT_NS / 1e9, q[2], w[2])  # the filter's time: from the first sample's stamp
        assert t0 + DT_NS not in drv.got[c.ESTIMATE_ATTITUDE.name] and node.steps == 2 and node.no_data == 0
        np.testing.assert_array_equal(drv.got[c.ESTIMATE_ATTITUDE.name][t0 + 2 * DT_NS], ref.out[:4])
        np.testing.assert_array_equal(drv.got[c.ESTIMATOR_COVARIANCE.name][t0 + 2 * DT_NS][1], ref.P)
        latency = node.statistics()["latency"]
        assert latency["steps"] == 2 and latency["late_steps"] == 1 and latency["latency_max_ms"] == pytest.approx(11.0)
        assert node.rejected_by_reason == {"stamp_in_past": 1, "invalid": 1}
    finally:
        drv.close()
        node.destroy_node()


def test_the_controller_takes_the_estimate_by_a_remap_and_answers_no_data_as_its_own_drop(ros_context) -> None:  # type: ignore[no-untyped-def]
    """``python -m sappc_controller --ros-args -r state/attitude:=estimate/attitude -r
    state/rate:=estimate/rate``, unchanged, in lockstep behind the estimator: a torque per sample
    computed from the estimate; a sample the estimator answers with "no data" (a dropped
    measurement) is answered by the controller at once with its last torque held, as when its own
    input is dropped."""
    from sappc_controller.node import ControllerNode
    from sappc_estimator.node import EstimatorNode

    est = EstimatorNode(context=ros_context, parameter_overrides=overrides())
    ctrl = ControllerNode(context=ros_context, parameter_overrides=_controller_overrides(),
                          cli_args=["--ros-args", "-r", "state/attitude:=estimate/attitude", "-r", "state/rate:=estimate/rate"])
    drv = Driver(ros_context, [est, ctrl], extra_topics=(c.REFERENCE_ATTITUDE, c.REFERENCE_RATE, c.REFERENCE_ACCELERATION))
    torques: dict[int, np.ndarray] = {}
    answers: dict[int, float] = {}
    qos = c.qos_profile()
    drv.node.create_subscription(c.CONTROL_TORQUE.msg_class, c.CONTROL_TORQUE.name, lambda m: torques.__setitem__(stamp_to_ns(m.header.stamp), torque_from_msg(m)), qos)
    drv.node.create_subscription(c.CONTROLLER_DIAGNOSTICS.msg_class, c.CONTROLLER_DIAGNOSTICS.name,
                                 lambda m: answers.__setitem__(round(m.data[0] * 1e9), diagnostics_from_msg(m)["status"][2]), qos)
    try:
        drv.matched(est)
        drv.spin_until(lambda: all(drv.pub[t.name].get_subscription_count() >= 1 for t in c.RELAYED_REFERENCE_TOPICS)
                       and all(est.pub[t.name].pub.get_subscription_count() >= 2 for t in (c.ESTIMATE_ATTITUDE, c.ESTIMATE_RATE)),
                       "the controller's subscriptions (the estimate: remapped)")
        q, w = measurements(3)
        for k in range(3):
            ns = k * DT_NS
            for topic, value in ((c.REFERENCE_ATTITUDE, [0.0, 0.0, 0.0, 1.0]), (c.REFERENCE_RATE, [0.0] * 3), (c.REFERENCE_ACCELERATION, [0.0] * 3)):
                msg = quaternion_msg(value, ns_to_stamp(ns), topic) if len(value) == 4 else vector3_msg(value, ns_to_stamp(ns), topic)
                drv.pub[topic.name].publish(msg)
            drv.send(ns, q[k], NO_DATA_W if k == 1 else w[k])
            drv.spin_until(lambda: ns in torques and ns in answers, f"the torque of {ns} ns")
        assert answers == {0: c.ANSWER_COMMANDED, DT_NS: c.ANSWER_HELD, 2 * DT_NS: c.ANSWER_COMMANDED}
        assert np.array_equal(torques[DT_NS], torques[0]) and np.any(torques[0] != 0.0)
        # the estimate's NaN attitude and rate: the contract's "no data", counted apart, not rejected
        assert ctrl.steps == 2 and ctrl.rejected == 0 and ctrl.rejected_by_reason == {} and ctrl.no_data_inputs == 2
    finally:
        drv.close()
        est.destroy_node()
        ctrl.destroy_node()


# ---- parameters ---------------------------------------------------------------------------------

BAD_PARAMETERS = {
    "tracker_noise_rad": ([0.0, 9.7e-6, 7.3e-5], "tracker_noise_rad must be > 0, got (0.0, 9.7e-06, 7.3e-05)"),
    "gyro_angle_random_walk_rad_sqrt_s": ([-1.0, 0.0, 0.0], "gyro_angle_random_walk_rad_sqrt_s must be >= 0, got (-1.0, 0.0, 0.0)"),
    "initial_bias_sigma_rad_s": ([1e-5, 1e-5], "initial_bias_sigma_rad_s must be one finite number or 3 (x, y, z), got (1e-05, 1e-05)"),
    "initial_q_BN": ([0.0, 0.0, 0.0, 2.0], "initial_q_BN must be a unit quaternion (x, y, z, w), got [0., 0., 0., 2.] with norm 2"),
    "gate_false_alarm": (1.5, "gate_false_alarm must be in [0, 1) (0: no gate), got 1.5"),
    "max_consecutive_rejections": (0, "max_consecutive_rejections must be an integer >= 1, got 0"),
    "mode": ("fast", "mode must be one of 'lockstep', 'realtime', got 'fast'"),
    "max_stamp_ahead_s": (-1.0, "max_stamp_ahead_s out of range"),
    "control_period_s": (0.0, "control_period_s must be finite and > 0, got 0.0"),
    "tracker_noise": ([1e-5] * 3, "unknown parameter 'tracker_noise' for the estimator node"),
}


@pytest.mark.parametrize("name", list(BAD_PARAMETERS))
def test_a_bad_parameter_stops_the_node_naming_itself_and_its_value(ros_context, name: str) -> None:
    from sappc_estimator.node import EstimatorNode

    value, words = BAD_PARAMETERS[name]
    with pytest.raises(ConfigError) as err:
        EstimatorNode(context=ros_context, parameter_overrides=overrides(**{name: value}))
    assert words in str(err.value) and "\n" not in str(err.value), str(err.value)


def test_the_help_speaks_of_the_values_a_parameter_takes() -> None:
    """The config's ``None`` is the parameter's ``[]``: the help of ``initial_q_BN`` (and of its
    sibling) says what to write, ``[]``, not the Python value behind it."""
    from sappc_estimator.params import FILTER_PARAMETERS

    helps = {p.name: p.description.replace("``", "") for p in FILTER_PARAMETERS}  # as --help prints it
    assert [name for name, text in helps.items() if "None" in text] == []
    assert helps["initial_q_BN"].startswith("[]: the filter starts at the first star-tracker sample")
    assert "([]: the tracker's noise)" in helps["initial_attitude_sigma_rad"]


def test_a_missing_tracker_noise_or_a_prior_without_its_sigma_is_named(ros_context) -> None:  # type: ignore[no-untyped-def]
    from sappc_estimator.node import EstimatorNode

    with pytest.raises(ConfigError, match="missing parameter tracker_noise_rad"):
        EstimatorNode(context=ros_context, parameter_overrides=[])
    with pytest.raises(ConfigError, match="initial_attitude_sigma_rad must be given with initial_q_BN"):
        EstimatorNode(context=ros_context, parameter_overrides=overrides(initial_q_BN=[0, 0, 0, 1]))  # integers: dynamic typing


def test_a_bad_parameter_exits_2_with_one_line() -> None:
    proc = subprocess.run([sys.executable, "-m", "sappc_estimator", "--ros-args", "--params-file", str(ROOT / "config" / "estimator_mekf.yaml"),
                           "-p", "gate_false_alarm:=1.5"], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 2 and proc.stderr == "error: gate_false_alarm must be in [0, 1) (0: no gate), got 1.5\n", proc.stderr


def test_parameters_round_trip_through_the_config_and_accept_one_number_for_three_axes() -> None:
    assert config_from_parameters(parameters_from_config(CONFIG)).params().tolist() == CONFIG.params().tolist()
    prior = MekfConfig(tracker_noise_rad=1e-5, initial_q_BN=(0.0, 0.0, 0.0, 1.0), initial_attitude_sigma_rad=0.1)
    assert parameters_from_config(prior)["initial_q_BN"] == [0.0, 0.0, 0.0, 1.0]
    assert config_from_parameters(parameters_from_config(prior)) == MekfConfig(
        tracker_noise_rad=(1e-5,) * 3, gyro_angle_random_walk_rad_sqrt_s=(0.0,) * 3, gyro_bias_random_walk_rad_s_sqrt_s=(0.0,) * 3,
        initial_bias_rad_s=(0.0,) * 3, initial_bias_sigma_rad_s=(1e-5,) * 3, initial_q_BN=(0.0, 0.0, 0.0, 1.0), initial_attitude_sigma_rad=(0.1,) * 3)
    assert config_from_parameters({"tracker_noise_rad": 2e-5}).params()[mekf.EP_R : mekf.EP_R + 3].tolist() == [2e-5 * 2e-5] * 3


def test_the_flight_parameters_file_is_what_sappc_params_writes_and_the_scenarios_filter() -> None:
    """``config/estimator_mekf.yaml`` is ``sappc params paper_tracking_flight.yaml --estimator``,
    and gives the filter the scenario's ``estimator: {kind: mekf}`` gives (its sensors' data sheet)."""
    import yaml

    from sappc.scenario import estimator_params_yaml, load_scenario, scenario_from_mapping
    from sappc_controller.params import parameters_from_yaml

    path = SCENARIOS / "paper_tracking_flight.yaml"
    text = (ROOT / "config" / "estimator_mekf.yaml").read_text()
    assert text == estimator_params_yaml(load_scenario(path))
    values = parameters_from_yaml(text, "estimator")
    period = values.pop("control_period_s")
    raw = yaml.safe_load(path.read_text())
    raw["estimator"] = {"kind": "mekf"}
    scenario = scenario_from_mapping(raw)
    assert scenario.estimator is not None and period == scenario.control_period_s
    assert config_from_parameters(values).params().tolist() == scenario.estimator.params().tolist()
    assert "# sensors.star_tracker.noise_rad" in text and "# sensors.gyro.angle_random_walk_rad_sqrt_s" in text
    proc = subprocess.run([sys.executable, "-m", "sappc", "params", str(path), "--estimator"], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0 and proc.stdout == text, proc.stderr


# ---- the tracker's own samples (issue 33) -------------------------------------------------------


@pytest.mark.parametrize("bad_q", [(0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.1), NO_DATA_Q], ids=["zero", "non-unit", "NaN"])
def test_an_invalid_tracker_sample_is_no_measurement_the_samples_naming_it_propagate(estimator, bad_q) -> None:  # type: ignore[no-untyped-def]
    """The tracker's sample of epoch 100 ms arrives invalid: it is rejected and counted (NaN in every value,
    the contract's "no data": counted apart, not rejected), and the
    samples that name it (100 to 190 ms) are stepped with the gyro alone (propagated: the filter is
    given the last valid sample's epoch, not new to it), as the kernel called with that epoch; the
    next sample (200 ms) updates."""
    node, drv = estimator
    q, w = measurements(21)
    ref = Reference()
    for k in range(21):
        ns = k * DT_NS
        drv.sample(ns, bad_q if k == 10 else q[k], w[k])
        epoch_s = 0.0 if 10 <= k < 20 else None  # the kernel: the last valid sample's epoch, as the node gives it
        status = ref.step(ns / 1e9, q[k], w[k], epoch_s)
        assert drv.got[c.ESTIMATOR_DIAGNOSTICS.name][ns]["status"] == status
        np.testing.assert_array_equal(drv.got[c.ESTIMATE_ATTITUDE.name][ns], ref.out[mekf.EO_Q : mekf.EO_Q + 4])
    statuses = [drv.got[c.ESTIMATOR_DIAGNOSTICS.name][k * DT_NS]["status"] for k in range(21)]
    assert statuses[10] == mekf.STATUS_PROPAGATED and statuses[20] == mekf.STATUS_UPDATED
    no_data = all(math.isnan(v) for v in bad_q)  # the contract's "no data": not a rejected message, counted apart
    assert node.rejected_by_reason == ({} if no_data else {"invalid": 1}) and node.no_data_inputs == int(no_data)
    assert node.filter.updates == 1 and node.no_data == 0


def test_a_tracker_sample_is_used_once_by_its_stamp_whatever_its_value_and_arrival(estimator) -> None:  # type: ignore[no-untyped-def]
    """Lockstep: a sample whose epoch names a tracker sample not yet arrived waits for it (the
    topics are not ordered among themselves); a held epoch never makes the filter update again, even
    when a sample with the same quaternion value arrives under a later stamp; a tracker sample older
    than one already named (a delayed one relayed late) is never used."""
    node, drv = estimator
    q, w = measurements(21)
    for k in range(10):
        drv.sample(k * DT_NS, q[k], w[k])
    assert node.filter.updates == 0  # sample 0 initialised
    # sample 10: its gyro and epoch first, the tracker's sample after: no answer until it has come
    drv.send(10 * DT_NS, q[10], w[10], topics=(c.SENSOR_GYRO, c.STATE_ATTITUDE_EPOCH))
    drv.spin_until(lambda: node._waiting is not None, "sample 10 waiting for its tracker sample")
    assert 10 * DT_NS not in drv.got[c.ESTIMATE_ATTITUDE.name]
    drv.send(10 * DT_NS, q[10], w[10], topics=(c.SENSOR_STAR_TRACKER,))
    drv.spin_until(lambda: drv.answered(10 * DT_NS), "sample 10 answered once its tracker sample came")
    assert node.filter.updates == 1
    for k in range(11, 20):  # held: the epoch names the 100 ms sample, used already
        drv.sample(k * DT_NS, q[k], w[k])
    assert node.filter.updates == 1
    # a late tracker sample of 50 ms (older than the 100 ms one already named): kept out, never used
    drv.send(5 * DT_NS, q[5], w[5], topics=(c.SENSOR_STAR_TRACKER,), epoch_ns=5 * DT_NS)
    drv.sample(20 * DT_NS, q[20], w[20])
    assert node.filter.updates == 2 and node.rejected_by_reason == {"stamp_in_past": 1}

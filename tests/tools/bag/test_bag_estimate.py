"""The estimator's topics in a bag, read back without ROS (:func:`sappc.bag.read.bag_estimate`): every
topic on the stamps of ``estimate/attitude``, the float arrays timed by their ``data[0]``, "no
data" rows NaN; the controller's diagnostics keep their own labels beside the estimator's float
arrays.  Bags written by ``tests/bagmaker.py`` (the mcap package and rclpy's serializer)."""

from __future__ import annotations

import numpy as np

from sappc.bag.read import bag_estimate, read_bag
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import covariance_msg, diagnostics_msg, estimator_diagnostics_msg, no_data_msg, quaternion_msg, vector3_msg

from bagmaker import write_bag

DT_NS = 10_000_000


def _estimate_messages(k: int, rng: np.random.Generator, no_data: bool) -> list[tuple[str, str, object, int]]:
    ns, t = k * DT_NS, k * DT_NS / 1e9
    out: list[tuple[str, str, object, int]] = []
    if no_data:
        for topic in c.ESTIMATOR_TOPICS[:5]:
            out.append((topic.name, topic.type_name, no_data_msg(topic, t), ns))
        P = None
    else:
        q = rng.standard_normal(4)
        out.append((c.ESTIMATE_ATTITUDE.name, c.ESTIMATE_ATTITUDE.type_name, quaternion_msg(q / np.linalg.norm(q), t, c.ESTIMATE_ATTITUDE), ns))
        for topic in c.ESTIMATOR_TOPICS[1:5]:
            out.append((topic.name, topic.type_name, vector3_msg(rng.standard_normal(3) * 1e-3, t, topic), ns))
        A = rng.standard_normal((6, 6))
        P = A @ A.T
    out.append((c.ESTIMATOR_COVARIANCE.name, c.ESTIMATOR_COVARIANCE.type_name, covariance_msg(t, P), ns))
    diag = [t, 1.5 * k, float(c.ESTIMATOR_NO_INPUT if no_data else 3), k, 0.0, 0.0, float(no_data), 0.0, 0.0, 60.0 + k, 0.0, 0.0]
    out.append((c.ESTIMATOR_DIAGNOSTICS.name, c.ESTIMATOR_DIAGNOSTICS.type_name, estimator_diagnostics_msg(diag), ns))
    return out


def test_the_estimate_reads_back_on_its_stamps_with_no_data_rows_nan(tmp_path) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(3)
    messages = [m for k in range(6) for m in _estimate_messages(k, rng, no_data=k == 4)]
    rows = {label: [0.5, 1.0, 2.0] for label in c.DIAGNOSTICS_LAYOUT[1:]}  # the controller's, after the estimator's float arrays
    messages += [(c.CONTROLLER_DIAGNOSTICS.name, c.CONTROLLER_DIAGNOSTICS.type_name, diagnostics_msg(k * DT_NS / 1e9, rows), k * DT_NS) for k in range(6)]
    bag = read_bag(write_bag(tmp_path / "est.mcap", messages))
    assert bag.diagnostics_labels == c.DIAGNOSTICS_LAYOUT  # not the covariance's or the estimator's labels
    assert bag.series[c.ESTIMATOR_COVARIANCE.name].stamps_ns.tolist() == [k * DT_NS for k in range(6)]  # timed by data[0]
    est = bag_estimate(bag)
    assert est is not None and est.stamps_ns.tolist() == [k * DT_NS for k in range(6)]
    sent = {(topic, log_ns): msg for topic, _, msg, log_ns in messages}
    for k in range(6):
        ns = k * DT_NS
        att = sent[(c.ESTIMATE_ATTITUDE.name, ns)]
        np.testing.assert_array_equal(est.q_BN[k], [att.quaternion.x, att.quaternion.y, att.quaternion.z, att.quaternion.w])  # type: ignore[attr-defined]
        for topic, got in ((c.ESTIMATE_RATE, est.omega_BN_B), (c.ESTIMATOR_GYRO_BIAS, est.gyro_bias_rad_s),
                           (c.ESTIMATOR_ATTITUDE_SIGMA, est.attitude_sigma_rad), (c.ESTIMATOR_BIAS_SIGMA, est.bias_sigma_rad_s)):
            v = sent[(topic.name, ns)].vector  # type: ignore[attr-defined]
            np.testing.assert_array_equal(got[k], [v.x, v.y, v.z])
        np.testing.assert_array_equal(est.covariance[k].ravel(), np.asarray(sent[(c.ESTIMATOR_COVARIANCE.name, ns)].data[1:]))  # type: ignore[attr-defined]
    assert np.all(np.isnan(est.q_BN[4])) and np.all(np.isnan(est.covariance[4])) and np.all(np.isfinite(est.covariance[3]))
    assert list(est.diagnostics) == list(c.ESTIMATOR_DIAGNOSTICS_LAYOUT)
    assert est.diagnostics["status"].tolist() == [3.0, 3.0, 3.0, 3.0, float(c.ESTIMATOR_NO_INPUT), 3.0]
    assert est.diagnostics["nis"].tolist() == [1.5 * k for k in range(6)]


def test_a_bag_without_an_estimator_has_no_estimate(tmp_path) -> None:  # type: ignore[no-untyped-def]
    msgs = [(c.STATE_RATE.name, c.STATE_RATE.type_name, vector3_msg([0.0, 0.0, 0.0], 0.0, c.STATE_RATE), 0)]
    assert bag_estimate(read_bag(write_bag(tmp_path / "plain.mcap", msgs))) is None

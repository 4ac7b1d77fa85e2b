"""The fault models of ``spacecraft_sim.core.faults``, each kind against what its definition says.

The injector node relays every sample through :class:`FaultSchedule` (``tests/test_nodes.py``
checks the relay itself); here each kind is checked sample by sample on a 10 ms grid, with the
window's edges, its state (freeze, stuck, delay) and the order in which faults compose.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from gnc_common.attitude import dot, quat_conjugate, quat_multiply
from spacecraft_sim.core.faults import FaultSchedule, faults_from_list
from gnc_common.validation import ConfigError

DT_S = 0.01
#: Unit quaternion products and normalisations: a few ulps (2.2e-16 each) per operation.
QUAT_TOL = 1e-15


def schedule(*entries: dict) -> FaultSchedule:  # type: ignore[type-arg]
    return FaultSchedule(faults_from_list(list(entries)))


def grid(n: int) -> list[tuple[float, int]]:
    """``(t [s], stamp [ns])`` of samples 0 .. n-1, as the plant stamps them (``k dt``)."""
    return [(k * DT_S, k * 10_000_000) for k in range(n)]


def torque(k: int) -> np.ndarray:
    """A distinct command per sample, so that a held or delayed one is recognisable."""
    return np.array([0.1 + k, -0.2 * k, 0.05 * k * k])


def sensor(k: int) -> tuple[np.ndarray, np.ndarray]:
    angle = 0.01 * k
    q = np.array([np.sin(angle / 2.0), 0.0, 0.0, np.cos(angle / 2.0)])
    return q, np.array([0.001 * k, -0.002, 0.003 * k])


def rotation_between(q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray:
    """``q_a^* ⊗ q_b``: the rotation taking ``q_a`` to ``q_b`` in ``a``'s body frame."""
    return quat_multiply(quat_conjugate(q_a)[None], q_b[None])[0]


def test_actuator_effectiveness_and_bias_act_inside_their_windows_only() -> None:
    s = schedule(
        {"kind": "actuator_effectiveness", "effectiveness": [0.5, 1.0, 0.0], "start_s": 0.02, "end_s": 0.04},
        {"kind": "actuator_bias", "bias_Nm": [0.01, 0.0, -0.02], "start_s": 0.03},
    )
    e, b = np.array([0.5, 1.0, 0.0]), np.array([0.01, 0.0, -0.02])
    expected = {0: torque(0), 1: torque(1), 2: e * torque(2), 3: e * torque(3) + b, 4: torque(4) + b, 5: torque(5) + b}
    for k, (t, _) in enumerate(grid(6)):
        np.testing.assert_array_equal(s.actuator(t, torque(k)), expected[k], err_msg=f"sample {k}")


def test_composition_follows_list_order() -> None:
    """Bias then effectiveness scales the bias too; the other order does not."""
    bias, eff = {"kind": "actuator_bias", "bias_Nm": [0.1, 0.1, 0.1]}, {"kind": "actuator_effectiveness", "effectiveness": [0.5, 0.5, 0.5]}
    u = np.array([0.2, 0.2, 0.2])
    np.testing.assert_array_equal(schedule(bias, eff).actuator(0.0, u), 0.5 * (u + 0.1))
    np.testing.assert_array_equal(schedule(eff, bias).actuator(0.0, u), 0.5 * u + 0.1)


def test_actuator_stuck_holds_the_window_first_command_then_releases() -> None:
    s = schedule({"kind": "actuator_stuck", "start_s": 0.02, "end_s": 0.05})
    got = [s.actuator(t, torque(k)) for k, (t, _) in enumerate(grid(7))]
    for k, want in enumerate([0, 1, 2, 2, 2, 5, 6]):
        np.testing.assert_array_equal(got[k], torque(want), err_msg=f"sample {k}")


@pytest.mark.parametrize("n", [1, 3])
def test_actuator_delay_delivers_the_command_n_samples_earlier(n: int) -> None:
    s = schedule({"kind": "delay", "path": "actuator", "samples": n, "start_s": 0.02})
    for k, (t, _) in enumerate(grid(10)):
        # before the window: live; its first n samples: the window's first (sample 2); then k - n
        want = k if k < 2 else max(2, k - n)
        np.testing.assert_array_equal(s.actuator(t, torque(k)), torque(want), err_msg=f"sample {k}")


def test_sensor_delay_freeze_and_dropout() -> None:
    delay = schedule({"kind": "delay", "path": "sensor", "samples": 2, "start_s": 0.0, "end_s": 0.05})
    freeze = schedule({"kind": "sensor_freeze", "start_s": 0.01, "end_s": 0.03})
    drop = schedule({"kind": "sensor_dropout", "start_s": 0.01, "end_s": 0.03})
    for k, (t, ns) in enumerate(grid(7)):
        q, w = sensor(k)
        for s, want in ((delay, k if k >= 5 else max(0, k - 2)), (freeze, 1 if k in (1, 2) else k)):
            got = s.sensor(t, ns, q, w)
            assert got is not None
            np.testing.assert_array_equal(got[0], sensor(want)[0], err_msg=f"sample {k}")
            np.testing.assert_array_equal(got[1], sensor(want)[1], err_msg=f"sample {k}")
        assert (drop.sensor(t, ns, q, w) is None) == (k in (1, 2)), f"sample {k}"


def test_reset_forgets_what_a_freeze_held() -> None:
    """``reset`` (a new run) forgets what a freeze held."""
    s = schedule({"kind": "sensor_freeze", "start_s": 0.0})
    q1, w1 = sensor(1)
    s.sensor(0.0, 0, *sensor(0))
    np.testing.assert_array_equal(s.sensor(0.01, 10_000_000, q1, w1)[0], sensor(0)[0])  # type: ignore[index]
    s.reset()
    np.testing.assert_array_equal(s.sensor(0.01, 10_000_000, q1, w1)[0], q1)  # type: ignore[index]


def test_sensor_bias_rotates_the_attitude_by_the_bias_in_the_body_frame() -> None:
    bias_rad = np.array([1e-3, -2e-3, 0.5e-3])
    s = schedule({"kind": "sensor_bias", "attitude_bias_rad": bias_rad.tolist(), "rate_bias_rad_s": [1e-4, 0.0, -1e-4]})
    for k, (t, ns) in enumerate(grid(5)):
        q, w = sensor(k)
        q_m, w_m, _ = s.sensor(t, ns, q, w)  # type: ignore[misc]
        assert abs(np.sqrt(dot(q_m, q_m)) - 1.0) < QUAT_TOL
        dq = rotation_between(q, q_m)
        # a rotation by |b| about b / |b|: vector part sin(|b|/2) b/|b|, scalar cos(|b|/2)
        half = np.linalg.norm(bias_rad) / 2.0
        np.testing.assert_allclose(dq[:3], np.sin(half) * bias_rad / np.linalg.norm(bias_rad), rtol=0, atol=QUAT_TOL)
        np.testing.assert_allclose(dq[3], np.cos(half), rtol=0, atol=QUAT_TOL)
        np.testing.assert_array_equal(w_m, w + np.array([1e-4, 0.0, -1e-4]))


def test_sensor_noise_is_a_pure_function_of_seed_and_stamp_with_the_stated_spread() -> None:
    """Same (seed, stamp): same noise, in any order; the spread matches the standard deviations."""
    std_att, std_rate = 1e-3, 2e-4
    entry = {"kind": "sensor_noise", "attitude_std_rad": std_att, "rate_std_rad_s": std_rate, "seed": 7}
    n = 4000
    q, w = sensor(3)
    forward = [schedule(entry).sensor(k * DT_S, k * 10_000_000, q, w) for k in range(n)]
    s = schedule(entry)
    backward = [s.sensor(k * DT_S, k * 10_000_000, q, w) for k in reversed(range(n))][::-1]
    for a, b in zip(forward, backward):
        np.testing.assert_array_equal(a[0], b[0])  # type: ignore[index]
        np.testing.assert_array_equal(a[1], b[1])  # type: ignore[index]
    other_seed = schedule({**entry, "seed": 8}).sensor(0.0, 0, q, w)
    assert not np.array_equal(other_seed[1], forward[0][1])  # type: ignore[index]
    rate_err = np.array([m[1] - w for m in forward])  # type: ignore[index]
    # small rotation: vector part of q^* ⊗ q_m is (rotation vector) / 2 to O(|n|^3) = 1e-9
    rot_err = np.array([2.0 * rotation_between(q, m[0])[:3] for m in forward])  # type: ignore[index]
    for err, std in ((rate_err, std_rate), (rot_err, std_att)):
        # 12,000 normal draws: the sample std's relative standard error is 1/sqrt(2 * 12000) = 0.65 %,
        # the mean's is 0.9 % of std; 4 % is more than 4 standard errors for both
        assert abs(err.std() / std - 1.0) < 0.04
        assert abs(err.mean()) < 0.04 * std
    assert all(abs(np.sqrt(dot(m[0], m[0])) - 1.0) < QUAT_TOL for m in forward)  # type: ignore[index]


def test_window_edges_are_on_the_grid_start_inclusive_end_exclusive() -> None:
    """A window [0.02, 0.05) sampled at k * 0.01 (which rounds: 3 * 0.01 = 0.030000000000000002) covers k = 2, 3, 4."""
    s = schedule({"kind": "sensor_dropout", "start_s": 0.02, "end_s": 0.05})
    dropped = [k for k, (t, ns) in enumerate(grid(8)) if s.sensor(t, ns, *sensor(k)) is None]
    assert dropped == [2, 3, 4]


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"kind": "actuator_effectiveness", "effectiveness": [1.2, 1.0, 1.0]}, "effectiveness must be in [0, 1]"),
        ({"kind": "delay", "path": "sensor", "samples": 0}, "delay.samples must be a positive integer"),
        ({"kind": "delay", "path": "both", "samples": 1}, "faults[0].path must be one of 'sensor', 'actuator', got 'both'"),
        ({"kind": "sensor_noise", "seed": -1}, "seed must be a non-negative integer"),
        ({"kind": "sensor_dropout", "start_s": 2.0, "end_s": 1.0}, "end_s (1.0) must be after start_s (2.0)"),
        ({"kind": "sensor_bias", "rate_bias_rad_s": [0.0, float("nan"), 0.0]}, "rate_bias_rad_s"),
        ({"kind": "jam"}, "faults[0].kind = 'jam' is unknown"),
    ],
)
def test_bad_fault_entries_name_the_value(entry: dict, message: str) -> None:  # type: ignore[type-arg]
    with pytest.raises(ConfigError, match=re.escape(message)):
        faults_from_list([entry])


def test_the_noise_model_rotates_about_the_body_axis_of_each_draw_and_adds_the_rate_draws() -> None:
    """The sensor-noise model (``spacecraft_sim.core.faults.noisy_measurement``): draws ``n[:3]``
    give the body-frame rotation vector ``attitude_std_rad * n[:3]``, ``n[3:]`` the rate error
    ``rate_std_rad_s * n[3:]``; checked one axis at a time against the closed form of a rotation
    by angle a about body axis i, ``q ⊗ (sin(a/2) e_i, cos(a/2))``, to 4e-16 (a few ulps: sin, cos, a
    product, the normalisation)."""
    from spacecraft_sim.core.faults import noisy_measurement

    q = np.array([0.3254, 0.4068, -0.3254, 0.7891])
    q /= np.linalg.norm(q)
    w = np.array([0.01, -0.02, 0.03])
    for i in range(3):
        n = np.zeros(6)
        n[i], n[3 + i] = 2.0, -3.0
        q_out, w_out = noisy_measurement(q, w, n, 0.1, 1e-3)
        dq = np.zeros(4)
        dq[i], dq[3] = np.sin(0.1), np.cos(0.1)  # angle 0.1 * 2 = 0.2 rad about axis i
        np.testing.assert_allclose(q_out, quat_multiply(q[None], dq[None])[0], rtol=0, atol=4e-16)
        expected_w = w.copy()
        expected_w[i] += 1e-3 * -3.0
        np.testing.assert_array_equal(w_out, expected_w)
    q_out, w_out = noisy_measurement(q, w, np.zeros(6), 0.1, 1e-3)  # zero draws: no rotation (angle 0 is no 0/0)
    np.testing.assert_allclose(q_out, q, rtol=0, atol=4e-16)
    np.testing.assert_array_equal(w_out, w)


def test_actuator_dropout_holds_the_last_delivered_torque_and_faults_after_it_see_the_held_one() -> None:
    """In its window the command is not delivered: the actuator holds the torque it last
    delivered (after the faults listed before the dropout); outside, every command is delivered
    and becomes the one held next.  A fault listed after the dropout does not act on the held one."""
    s = schedule(
        {"kind": "actuator_bias", "bias_Nm": [0.01, 0.0, 0.0], "start_s": 0.0},
        {"kind": "actuator_dropout", "start_s": 0.02, "end_s": 0.04},
        {"kind": "actuator_effectiveness", "effectiveness": [0.5, 0.5, 0.5], "start_s": 0.0},
    )
    b = np.array([0.01, 0.0, 0.0])
    delivered = [s.actuator(t, torque(k)) for k, (t, _) in enumerate(grid(6))]
    expected = {0: 0.5 * (torque(0) + b), 1: 0.5 * (torque(1) + b), 2: 0.5 * (torque(1) + b), 3: 0.5 * (torque(1) + b),
                4: 0.5 * (torque(4) + b), 5: 0.5 * (torque(5) + b)}
    for k, u in enumerate(delivered):
        np.testing.assert_array_equal(u, expected[k], err_msg=f"sample {k}")


def test_reference_dropout_drops_the_reference_inside_its_window_only() -> None:
    s = schedule({"kind": "sensor_bias", "rate_bias_rad_s": [1e-3, 0.0, 0.0]}, {"kind": "reference_dropout", "start_s": 0.02, "end_s": 0.04})
    assert [s.reference(t) for t, _ in grid(6)] == [True, True, False, False, True, True]
    assert schedule().reference(0.0) and schedule({"kind": "sensor_dropout"}).reference(0.03)

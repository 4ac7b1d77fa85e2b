"""Sensor models (spacecraft_sim.core.sensors): the white-noise model as the special case bit for
bit, the star tracker's rate, hold and outages, the gyro's noise and bias walk, validation, and the
closed loop with sensors (the controller sees the measurement, the record keeps the truth)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from gnc_common.validation import ConfigError
from sappc.offline import compiled_loop
from sappc.scenario import scenario_from_mapping
from spacecraft_sim.core import kernels
from spacecraft_sim.core.sensors import N_SENSOR_DRAWS, Gyro, Sensors, StarTracker, measure, white_noise_params

ROOT = Path(__file__).resolve().parents[2]
DT = 0.01


def _truth(k: int) -> tuple[np.ndarray, np.ndarray]:
    a = 0.3 + 0.01 * k
    q = np.array([np.sin(a / 2) * 0.6, np.sin(a / 2) * 0.8, 0.0, np.cos(a / 2)])
    return q, np.array([0.01, -0.02, 0.005]) * np.cos(0.1 * k)


def _measure_all(sensors: Sensors, draws: np.ndarray, dt: float = DT) -> np.ndarray:
    prm, outages = sensors.params(dt), sensors.outages()
    held, bias = np.zeros(5), prm[10:13].copy()
    out = np.zeros((draws.shape[0], 8))
    for k in range(draws.shape[0]):
        q, w = _truth(k)
        measure(k, k * dt, k * dt, q, w, draws[k], prm, outages, held, bias, out[k])
    return out


def test_the_white_noise_model_is_the_special_case_bit_for_bit() -> None:
    """The earlier model (``kernels.noisy_measurement``, a tracker at every sample, a gyro without
    bias) and :func:`measure` with :func:`white_noise_params` give the same bits."""
    rng = np.random.default_rng(1)
    prm = white_noise_params(3e-6, 2e-6)
    held, bias, y = np.zeros(5), np.zeros(3), np.zeros(8)
    for k in range(500):
        q, w = _truth(k)
        n = rng.standard_normal(6)
        measure(k, k * DT, k * DT, q, w, n, prm, np.zeros((0, 2)), held, bias, y)
        q_old, w_old = np.zeros(4), np.zeros(3)
        kernels.noisy_measurement(q, w, n, 3e-6, 2e-6, q_old, w_old)
        assert np.array_equal(y[:4], q_old) and np.array_equal(y[4:7], w_old) and y[7] == k * DT


def test_the_star_tracker_updates_at_its_rate_and_holds_through_outages() -> None:
    sigma = np.array([1e-5, 1e-5, 5e-5])
    sensors = Sensors(star_tracker=StarTracker(noise_rad=tuple(sigma), rate_hz=10.0, outages_s=((0.5, 0.8),)))
    draws = np.random.default_rng(2).standard_normal((120, N_SENSOR_DRAWS))
    y = _measure_all(sensors, draws)
    changed = np.flatnonzero(np.any(np.diff(y[:, :4], axis=0) != 0.0, axis=1)) + 1
    assert changed.tolist() == [10, 20, 30, 40, 80, 90, 100, 110]  # every 10th sample; none at 50, 60, 70 (outage)
    assert np.array_equal(y[:, 4:7], np.array([_truth(k)[1] for k in range(120)]))  # no gyro: exact rates
    # at an update the error is the rotation vector sigma * n in the body frame: q_true* (x) q_meas = (r/2, 1) to O(r^3)
    from gnc_common.attitude import error_quaternion

    for k in (0, 10, 20, 30, 40, 80, 90, 100, 110):
        err = error_quaternion(_truth(k)[0], y[k, :4])
        assert np.allclose(err[:3] * np.sign(err[3]), sigma * draws[k, :3] / 2, rtol=0, atol=1e-12), k


def test_the_gyro_noise_and_bias_walk_have_their_stated_statistics() -> None:
    """ARW N gives per-sample noise N / sqrt(dt); the bias walks by K sqrt(dt) per sample from b0
    (its increments are exactly the scaled draws).  Sample std of 20,000 draws: within 3 %
    (its standard error is 0.5 %)."""
    N, K, b0 = 2e-6, 1e-8, np.array([1e-5, -2e-5, 3e-5])
    sensors = Sensors(gyro=Gyro(angle_random_walk_rad_sqrt_s=N, bias_random_walk_rad_s_sqrt_s=K, initial_bias_rad_s=tuple(b0)))
    draws = np.random.default_rng(3).standard_normal((20_000, N_SENSOR_DRAWS))
    y = _measure_all(sensors, draws)
    truth = np.array([_truth(k)[1] for k in range(20_000)])
    bias = b0 + np.vstack([np.zeros(3), np.cumsum(K * np.sqrt(DT) * draws[:-1, 6:9], axis=0)])
    white = y[:, 4:7] - truth - bias
    assert np.allclose(white / (N / np.sqrt(DT)), draws[:, 3:6], rtol=0, atol=1e-6)  # noise = sigma n, up to rounding of rates ~1e-2
    assert np.all(np.abs(white.std(axis=0) / (N / np.sqrt(DT)) - 1) < 0.03)
    assert np.array_equal(y[:, :4], np.array([_truth(k)[0] for k in range(20_000)]))  # no tracker: exact attitude


@pytest.mark.parametrize(("sensors", "key"), [
    ({"star_tracker": {"rate_hz": 30.0}}, "rate_hz"),
    ({"star_tracker": {"rate_hz": 0.0}}, "sensors.star_tracker.rate_hz"),
    ({"star_tracker": {"noise_rad": -1e-6}}, "sensors.star_tracker.noise_rad"),
    ({"star_tracker": {"noise_rad": [1e-6, 1e-6]}}, "sensors.star_tracker.noise_rad"),
    ({"star_tracker": {"outages_s": [[0.0, 1.0]]}}, "sensors.star_tracker.outages_s"),
    ({"star_tracker": {"outages_s": [[2.0, 1.0]]}}, "sensors.star_tracker.outages_s"),
    ({"gyro": {"angle_random_walk_rad_sqrt_s": -1.0}}, "sensors.gyro.angle_random_walk_rad_sqrt_s"),
    ({"gyro": {"bias_random_walk_rad_s_sqrt_s": [0.0, -1.0, 0.0]}}, "sensors.gyro.bias_random_walk_rad_s_sqrt_s"),
    ({"gyro": {"drift": 1.0}}, "sensors.gyro.drift"),
    ({"seed": -3}, "sensors.seed"),
    ({"magnetometer": {}}, "sensors.magnetometer"),
])
def test_bad_sensor_sections_stop_with_an_error_naming_the_key(sensors: dict[str, Any], key: str) -> None:
    raw = yaml.safe_load((ROOT / "config" / "scenarios" / "paper_tracking.yaml").read_text())
    raw["sensors"] = sensors
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        scenario_from_mapping(raw)


@pytest.mark.parametrize(("rate_hz", "message"), [
    ("ten", "sensors.star_tracker.rate_hz must be a number, got 'ten'"),  # not "must be > 0": it is not a number at all
    ([10.0], "sensors.star_tracker.rate_hz must be a number, got (10.0,)"),
    (0.0, "sensors.star_tracker.rate_hz must be finite and > 0, got 0.0"),
    (float("inf"), "sensors.star_tracker.rate_hz must be finite and > 0, got inf"),
])
def test_a_tracker_rate_that_is_not_a_positive_number_says_which_it_is_not(rate_hz: Any, message: str) -> None:
    raw = yaml.safe_load((ROOT / "config" / "scenarios" / "paper_tracking.yaml").read_text())
    raw["sensors"] = {"star_tracker": {"rate_hz": rate_hz}}
    with pytest.raises(ConfigError) as err:
        scenario_from_mapping(raw)
    assert str(err.value) == message


def _loop_raw(duration_s: float = 6.0) -> dict[str, Any]:
    raw = yaml.safe_load((ROOT / "config" / "scenarios" / "paper_tracking.yaml").read_text())
    raw["duration_s"] = duration_s
    raw["metrics"]["steady_from_s"] = duration_s / 2
    raw["sensors"] = {"star_tracker": {"noise_rad": [5e-6, 5e-6, 3e-5], "rate_hz": 10.0, "outages_s": [[2.0, 2.5]]},
                      "gyro": {"angle_random_walk_rad_sqrt_s": 1.5e-6, "bias_random_walk_rad_s_sqrt_s": 1e-9,
                               "initial_bias_rad_s": [5e-6, -5e-6, 5e-6]}, "seed": 11}
    return dict(raw)


def test_in_the_loop_the_controller_sees_the_measurement_and_the_record_the_truth() -> None:
    """The compiled loop with sensors equals a step-by-step loop of the controller's Python step fed
    :func:`measure` (bit for bit), records the true state, and the same seed gives the same run."""
    raw = _loop_raw()
    s = scenario_from_mapping(raw)
    assert s.sensors is not None
    from sappc.offline.simulate import run_scenario

    _, run = run_scenario(s, keep_history=True)
    h = run.history
    assert h is not None
    inp = compiled_loop.prepare(s)
    ctrl = s.build_controller()
    x = inp.plant.x0[0].copy()
    draws = s.sensors.draws(inp.t.size)
    prm, outages = s.sensors.params(s.control_period_s), s.sensors.outages()
    held, bias, y = np.zeros(5), prm[10:13].copy(), np.zeros(8)
    for k in range(inp.t.size):
        assert np.array_equal(h.q_BN[k, 0], x[:4]) and np.array_equal(h.omega_BN_B[k, 0], x[4:])  # the truth is recorded
        measure(k, inp.t[k], int(inp.grid.t_ns[k]) / 1e9, x[:4], x[4:7], draws[k], prm, outages, held, bias, y)
        tau = np.asarray(ctrl.step(int(inp.grid.t_ns[k]) / 1e9, inp.grid.dt, y[:4], y[4:7], inp.grid.ref_q[k], inp.grid.ref_w[k], inp.grid.ref_wd[k]).torque_B, dtype=np.float64)
        assert np.array_equal(h.torque_B[k, 0], tau), k
        if k < inp.t.size - 1:
            kernels.propagate(x, np.minimum(np.maximum(tau, -0.5), 0.5) + inp.disturbance.table[k], inp.grid.dt, inp.plant.substeps, inp.plant.J[0], inp.plant.J_inv[0])
    other = copy.deepcopy(raw)
    other["sensors"]["seed"] = 12
    a = compiled_loop.simulate_compiled(s)
    assert np.array_equal(a.out, compiled_loop.simulate_compiled(scenario_from_mapping(raw)).out)  # same seed, same run
    assert not np.array_equal(a.out, compiled_loop.simulate_compiled(scenario_from_mapping(other)).out)

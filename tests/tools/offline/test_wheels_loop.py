"""Reaction wheels in the closed loop (issue 16): the scenario's ``actuator`` section, the compiled
loop with wheels against a step-by-step loop of the public kernels, run k of a batch against the
run alone, the ideal actuator unchanged, momentum conservation through the whole loop, the motor
and speed limits, and the wheel metrics."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from conftest import cut_short
from gnc_common.attitude import quat_to_dcm_BN
from gnc_common.validation import ConfigError
from sappc.offline import compiled_loop
from sappc.offline.simulate import run_scenario, simulate
from sappc.scenario import scenario_from_mapping
from spacecraft_sim.core.wheels import ReactionWheels, angular_momentum_B, propagate_wheels, wheel_speeds, wheel_torques

ROOT = Path(__file__).resolve().parents[3]
WHEELS_FILE = ROOT / "config" / "scenarios" / "paper_tracking_wheels.yaml"
PAPER_FILE = ROOT / "config" / "scenarios" / "paper_tracking.yaml"


def _raw(path: Path = WHEELS_FILE, duration_s: float = 8.0) -> dict[str, Any]:
    raw = yaml.safe_load(path.read_text())
    cut_short(raw, duration_s)
    raw["metrics"]["steady_from_s"] = min(raw["metrics"]["steady_from_s"], duration_s / 2)
    return dict(raw)


def test_the_wheel_scenario_loads_its_wheels_and_the_ideal_kind_is_the_default() -> None:
    s = scenario_from_mapping(_raw())
    assert s.wheels is not None and s.wheels.n == 4
    assert s.actuator.max_torque_Nm == 0.15
    assert scenario_from_mapping(_raw(PAPER_FILE)).wheels is None


def test_kind_ideal_written_out_is_the_default_bit_for_bit() -> None:
    raw = _raw(PAPER_FILE, 5.0)
    explicit = copy.deepcopy(raw)
    explicit["actuator"]["kind"] = "ideal"
    a = compiled_loop.simulate_compiled(scenario_from_mapping(raw))
    b = compiled_loop.simulate_compiled(scenario_from_mapping(explicit))
    assert a.wheels.shape[2] == 0 and a.x_final.shape == (1, 7)
    assert np.array_equal(a.out, b.out) and np.array_equal(a.x, b.x)


def _step_by_step(raw: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The loop of :func:`compiled_loop._run_one` with wheels, written with the public pieces: the
    controller's Python step (the node's call), the reference and the disturbance as the compiled
    loop tabulates them, :func:`wheel_torques` and :func:`propagate_wheels` per sample."""
    s = scenario_from_mapping(raw)
    inp = compiled_loop.prepare(s)
    wheels = s.wheels
    assert wheels is not None
    ctrl = s.build_controller()
    G, Gp, prm = inp.actuator.G[0], inp.actuator.G_pinv[0], inp.actuator.params[0]
    x = inp.plant.x0[0].copy()
    T = inp.t.size
    torques, speeds, states = np.zeros((T, 3)), np.zeros((T, wheels.n)), np.zeros((T, x.size))
    d = inp.disturbance.table
    for k in range(T):
        states[k] = x
        tau = np.asarray(ctrl.step(int(inp.grid.t_ns[k]) / 1e9, inp.grid.dt, x[:4], x[4:7], inp.grid.ref_q[k], inp.grid.ref_w[k], inp.grid.ref_wd[k]).torque_B, dtype=np.float64)
        torques[k] = tau
        u = np.zeros(wheels.n)
        wheel_torques(tau, Gp, G, prm, x, u)
        speeds[k] = wheel_speeds(wheels, x)
        if k < T - 1:
            propagate_wheels(x, u, d[k].copy(), inp.grid.dt, inp.plant.substeps, inp.plant.J[0], inp.plant.J_inv[0], G, prm)
    return torques, speeds, states


def test_the_compiled_loop_with_wheels_equals_a_step_by_step_loop_of_the_public_kernels() -> None:
    """Bit for bit: the same kernels in the same order (the node's step; the plant's wheel kernels)."""
    raw = _raw(duration_s=6.0)
    run = compiled_loop.simulate_compiled(scenario_from_mapping(raw))
    torques, speeds, states = _step_by_step(raw)
    assert np.array_equal(run.out[0, :, compiled_loop.O_TORQUE, :3], torques)
    assert np.array_equal(run.wheels[0, :, :, 0], speeds)
    assert np.array_equal(run.x[0], states[:, :7])
    assert np.array_equal(run.x_final[0], states[-1])


def test_run_k_of_a_batch_with_dispersed_wheels_is_the_run_alone() -> None:
    s = scenario_from_mapping(_raw(duration_s=4.0))
    assert s.wheels is not None
    sets = [ReactionWheels(spin_axes_B="pyramid", spin_inertia_kg_m2=0.0796 * f, max_torque_Nm=0.2 * f, max_speed_rad_s=628.3,
                           coulomb_friction_Nm=1e-3, viscous_friction_Nm_s=1e-5, initial_speed_rad_s=10.0 * f) for f in (0.8, 1.0, 1.3)]
    q0 = np.stack([s.q_BN0] * 3)
    inp = compiled_loop.prepare(s, q_BN0=q0, wheels=sets)
    batch = compiled_loop.run_batch(inp, 1)
    assert not np.array_equal(batch.wheels[0], batch.wheels[2])  # the dispersion changes the runs
    for n in range(3):
        alone = compiled_loop.run_single(inp, n, 1)
        assert np.array_equal(batch.wheels[n], alone.wheels[0]) and np.array_equal(batch.x_final[n], alone.x_final[0])
    with pytest.raises(ValueError, match="one wheel set per run"):
        compiled_loop.prepare(s, q_BN0=q0, wheels=sets[:2])


def test_total_angular_momentum_is_conserved_through_the_closed_loop_without_disturbance() -> None:
    """No external torque: whatever SAPPC commands, the wheels only move momentum between themselves
    and the body; H in the inertial frame stays put (RK4 at 10 ms: 1e-12 relative of |H|)."""
    raw = _raw(duration_s=20.0)
    raw["disturbances"] = []
    raw["initial_state"]["omega_BN_B_rad_s"] = [0.01, -0.02, 0.015]
    s = scenario_from_mapping(raw)
    assert s.wheels is not None
    run = compiled_loop.simulate_compiled(s)
    inp = compiled_loop.prepare(s)
    H_N0 = quat_to_dcm_BN(inp.plant.x0[0, :4]).T @ angular_momentum_B(s.inertia_kg_m2, s.wheels, inp.plant.x0[0])
    x_end = run.x_final[0]
    H_N1 = quat_to_dcm_BN(x_end[:4]).T @ angular_momentum_B(s.inertia_kg_m2, s.wheels, x_end)
    assert np.max(np.abs(run.wheels[0, :, :, 1])) > 0.05  # the controller did work the wheels
    assert np.linalg.norm(H_N1 - H_N0) <= 1e-12 * np.linalg.norm(H_N0)


def test_the_motor_and_speed_limits_hold_in_the_loop_and_the_metrics_report_them() -> None:
    """Wheels too weak for the transient (20 mN m) and too slow to absorb it (3 rad/s): no motor
    torque beyond its limit, no wheel faster than its limit plus one period's acceleration, and the
    metrics report the largest speed and torque."""
    raw = _raw(duration_s=20.0)
    raw["actuator"]["wheels"].update(max_torque_Nm=0.02, max_speed_rad_s=3.0)
    s = scenario_from_mapping(raw)
    result = simulate(s)
    assert result.history.wheel_speed_rad_s is not None and result.history.wheel_torque_Nm is not None
    speed, torque = np.abs(result.history.wheel_speed_rad_s[:, 0]), np.abs(result.history.wheel_torque_Nm[:, 0])
    assert torque.max() <= 0.02
    # a wheel reaches its limit on the sample after the one that crosses it: one period of the
    # largest motor acceleration past it (the body's rate, ~1e-3 rad/s per period here, comes on top: twice that, generously)
    one_step = 2 * 0.02 / 0.0796 * s.control_period_s
    assert 3.0 <= speed.max() <= 3.0 + one_step
    assert np.count_nonzero(speed >= 3.0 - one_step) > 100  # held at the limit, not crossed once
    assert result.metrics["max_abs_wheel_speed_rad_s"] == pytest.approx(speed.max(), rel=0, abs=0)
    assert result.metrics["max_abs_wheel_torque_Nm"] == torque.max()
    # what the motors did not make of the command (wheels.png's third panel): zero while no motor is
    # at its limit and no wheel at its speed limit, not zero when one is
    assert s.wheels is not None
    undelivered = np.abs(result.history.torque_B[:, 0] + result.history.wheel_torque_Nm[:, 0] @ s.wheels.G.T).max(axis=1)
    free = (torque.max(axis=1) < 0.02) & (speed.max(axis=1) < 3.0)
    assert np.all(undelivered[free] < 1e-15) and np.any(undelivered[~free] > 1e-3)


def test_an_ideal_run_has_no_wheel_metrics_and_a_wheel_requirement_fails_it() -> None:
    from sappc.evaluation.requirements import failed_requirements

    metrics, _ = run_scenario(scenario_from_mapping(_raw(PAPER_FILE, 3.0)))
    m = metrics.run_metrics(0)
    assert "max_abs_wheel_speed_rad_s" not in m
    failed = failed_requirements(m, {"max_abs_wheel_speed_rad_s_max": 100.0})
    assert failed[-1] == "max_abs_wheel_speed_rad_s is unknown (required <= 100)"  # after the 3 s cut's loss of control (1.5 s steady)


@pytest.mark.parametrize(("change", "key"), [
    ({"kind": "magnetorquers"}, "actuator.kind"),
    ({"wheels": None}, "actuator.wheels"),
    ({"kind": "ideal"}, "actuator.wheels"),
    ({"wheels": {"spin_inertia_kg_m2": -0.1}}, "actuator.wheels.spin_inertia_kg_m2"),
    ({"wheels": {"spin_inertia_kg_m2": [0.1, 0.1, 0.1]}}, "actuator.wheels.spin_inertia_kg_m2"),
    ({"wheels": {"max_torque_Nm": 0.0}}, "actuator.wheels.max_torque_Nm"),
    ({"wheels": {"max_speed_rad_s": -5.0}}, "actuator.wheels.max_speed_rad_s"),
    ({"wheels": {"viscous_friction_Nm_s": -1e-5}}, "actuator.wheels.viscous_friction_Nm_s"),
    ({"wheels": {"spin_axes_B": [[1, 0, 0], [0, 1, 0], [0, 0, 0]]}}, "actuator.wheels.spin_axes_B"),
    ({"wheels": {"spin_axes_B": [[1, 0, 0], [0, 1, 0], [1, 1, 0]]}}, "actuator.wheels.spin_axes_B"),
    ({"wheels": {"spin_axes_B": "tetrahedron"}}, "actuator.wheels.spin_axes_B"),
    ({"wheels": {"max_rpm": 6000}}, "actuator.wheels.max_rpm"),
])
def test_bad_actuator_sections_stop_with_an_error_naming_the_key(change: dict[str, Any], key: str) -> None:
    raw = _raw()
    act = raw["actuator"]
    for k, v in change.items():
        if k == "wheels" and isinstance(v, dict):
            act["wheels"] = {**act["wheels"], **v}
        elif v is None:
            act.pop(k)
        else:
            act[k] = v
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        scenario_from_mapping(raw)

"""Reaction wheels on the ROS 2 graph (issue 16): ``joint_states`` decoded as rclpy does, and the
wheel scenario through ``sappc run`` in lockstep equal to the offline run, wheel records included."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml
from rclpy.serialization import deserialize_message, serialize_message

from sappc.bag import cdr
from sappc.bag.read import bag_run, read_bag
from sappc.offline import compiled_loop
from sappc.scenario import scenario_from_mapping
from sappc_msgs_py.contract import WHEEL_STATES
from sappc_msgs_py.convert import joint_state_msg

from conftest import ROOT, SAPPC, SCENARIOS


def _payloads(n_msgs: int, n_wheels: int, rng: np.random.Generator) -> list[bytes]:
    msg = None
    out = []
    for k in range(n_msgs):
        msg = joint_state_msg(300.0 * rng.standard_normal(n_wheels), 0.1 * rng.standard_normal(n_wheels), 0.01 * k + 1e9, out=msg)
        out.append(serialize_message(msg))
    return out


@pytest.mark.parametrize("n_wheels", [3, 4, 6])
def test_joint_states_decode_as_rclpy_deserialises_them(n_wheels: int) -> None:
    from sensor_msgs.msg import JointState

    rng = np.random.default_rng(n_wheels)
    payloads = _payloads(50, n_wheels, rng)
    odd = JointState()  # another layout of another length: positions are not the contract's
    odd.name, odd.position, odd.velocity, odd.effort = ["a"], [1.0], [2.0], [3.0]
    payloads.append(serialize_message(odd))
    buf = b"".join(payloads)
    start = np.cumsum([0] + [len(p) for p in payloads[:-1]])
    d = cdr.decode(WHEEL_STATES.type_name, buf, start, np.array([len(p) for p in payloads]))
    assert d is not None and d.undecodable == 1 and d.slow_path == 0
    truth = [deserialize_message(p, JointState) for p in payloads[:-1]]
    assert np.array_equal(d.values, np.array([list(m.velocity) + list(m.effort) for m in truth]))
    assert np.array_equal(d.stamps_ns, np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in truth]))
    assert d.labels == tuple(f"wheel_{i + 1}" for i in range(n_wheels)) and d.frame_ids == ("body",)


@pytest.mark.slow
def test_the_wheel_scenario_through_the_graph_equals_the_offline_run(tmp_path: Path) -> None:
    """Lockstep, 4 s: the bag's wheel speeds and motor torques and its attitude equal the offline
    run's bit for bit (the plant node calls the offline loop's wheel kernels in the same order),
    and the report's metrics carry the wheel metrics."""
    raw = yaml.safe_load((SCENARIOS / "paper_tracking_wheels.yaml").read_text())
    raw["duration_s"] = 4.0
    raw["metrics"]["steady_from_s"] = 2.0
    path = tmp_path / "wheels.yaml"
    path.write_text(yaml.safe_dump(raw))
    out = tmp_path / "run"
    proc = subprocess.run([*SAPPC, "run", str(path), "--out", str(out), "--json", str(tmp_path / "m.json")], capture_output=True, text=True,
                          timeout=600, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    offline = compiled_loop.simulate_compiled(scenario_from_mapping(raw))
    run = bag_run(read_bag(out / "bag"))
    h = run.history
    assert h.wheel_speed_rad_s is not None and h.wheel_torque_Nm is not None
    assert np.array_equal(h.wheel_speed_rad_s[:, 0], offline.wheels[0, :, :, 0])
    assert np.array_equal(h.wheel_torque_Nm[:, 0], offline.wheels[0, :, :, 1])
    assert np.array_equal(h.q_BN[:, 0], offline.x[0, :, :4])
    report = json.loads((tmp_path / "m.json").read_text())
    assert report["metrics"]["max_abs_wheel_speed_rad_s"] == float(np.abs(offline.wheels[0, :, :, 0]).max())

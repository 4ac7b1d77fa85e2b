"""``sappc rerun`` on bags of another controller node (no input stamps in diagnostics): the
recorded inputs go through the controller node's own pairing (:mod:`sappc_controller.inputs`),
the state the controller read is the fault relay's (:func:`~sappc_msgs_py.contract.consumed_names`),
and a sample with an input missing is skipped, never paired with a neighbour."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from bagmaker import write_bag

from sappc.analysis.rerun import rerun_bag
from sappc.bag.read import read_bag
from sappc_controller.params import CONTROLLER_CLASSES, controller_from_parameters_file
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import clock_msg, quaternion_msg, torque_msg, vector3_msg

from conftest import ROOT

PARAMS = ROOT / "config" / "controller_sappc.yaml"
Q0 = np.array([0.3254, 0.4068, -0.3254, 0.7891]) / np.linalg.norm([0.3254, 0.4068, -0.3254, 0.7891])
NS = 1_000_000_000


def _controller():  # type: ignore[no-untyped-def]
    kind, config, dt = controller_from_parameters_file(PARAMS.read_text(), source=str(PARAMS))
    return CONTROLLER_CLASSES[kind](config), dt


def _inputs(k: int, t_s: float) -> list[tuple[c.Topic, np.ndarray]]:
    """The controller's inputs of sample ``k`` (state as the relay delivered it)."""
    w = np.array([0.01, -0.02, 0.005]) * np.cos(0.1 * k)
    return [(c.faulty(c.STATE_ATTITUDE), Q0), (c.faulty(c.STATE_RATE), w), (c.REFERENCE_ATTITUDE, np.array([0.0, 0.0, 0.0, 1.0])),
            (c.REFERENCE_RATE, np.zeros(3)), (c.REFERENCE_ACCELERATION, np.zeros(3))]


def _msg(topic: c.Topic, value: np.ndarray, t_s: float):  # type: ignore[no-untyped-def]
    return quaternion_msg(value, t_s, topic) if value.size == 4 else vector3_msg(value, t_s, topic)


def test_a_lockstep_bag_pairs_equal_stamps_of_the_relayed_state_as_the_node_does(tmp_path: Path) -> None:
    controller, dt = _controller()
    messages = []
    expected = {}
    for k in range(30):
        t, t_ns = k * dt, round(k * dt * NS)
        log = k * 10_000_000
        messages.append((c.CLOCK.name, c.CLOCK.type_name, clock_msg(t), log))
        inputs = _inputs(k, t)
        # the truth state is in the bag too, other values: the controller read the relay's
        messages.append((c.STATE_ATTITUDE.name, c.STATE_ATTITUDE.type_name, quaternion_msg([0.0, 0.0, 0.0, 1.0], t, c.STATE_ATTITUDE), log))
        for i, (topic, value) in enumerate(reversed(inputs)):  # arrival order differs from step order
            if k == 7 and topic == c.REFERENCE_RATE:
                continue  # sample 7 never completes
            messages.append((topic.name, topic.type_name, _msg(topic, value, t), log + i))
        if k != 7:
            expected[t_ns] = controller.step(t_ns / NS, dt, *(v for _, v in inputs)).torque_B
        torque = expected.get(t_ns, np.array([0.1, 0.1, 0.1]))  # sample 7: whatever another node sent
        messages.append((c.CONTROL_TORQUE.name, c.CONTROL_TORQUE.type_name, torque_msg(torque, t, c.CONTROL_TORQUE), log + 9))
    result = rerun_bag(read_bag(write_bag(tmp_path / "lockstep.mcap", messages)), PARAMS)
    assert result.mode == "lockstep" and result.pairing == "equal stamps"
    assert result.skipped == {"an input of the sample is not in the bag": 1}
    assert result.stamps_ns.tolist() == sorted(expected) and result.identical == len(expected) == 29


def test_a_real_time_bag_takes_the_latest_input_received_before_each_torque(tmp_path: Path) -> None:
    controller, dt = _controller()
    messages = []
    latest: dict[str, np.ndarray] = {}
    n = 0
    for k in range(30):
        t = 100.0 + k * dt  # epoch-like times
        for i, (topic, value) in enumerate(_inputs(k, t)):
            stamp = t + 0.001 * i  # no common stamps in real time
            log = round(stamp * NS) + 500_000
            messages.append((topic.name, topic.type_name, _msg(topic, value, stamp), log))
            latest[topic.name] = value
        t_torque = t + 0.007
        torque = controller.step(round(t_torque * NS) / NS, dt, *(latest[tp.name] for tp, _ in _inputs(k, t))).torque_B
        messages.append((c.CONTROL_TORQUE.name, c.CONTROL_TORQUE.type_name, torque_msg(torque, t_torque, c.CONTROL_TORQUE), round(t_torque * NS) + 500_000))
        n += 1
    result = rerun_bag(read_bag(write_bag(tmp_path / "rt.mcap", messages)), PARAMS)
    assert result.mode == "realtime" and result.pairing == "arrival at the recorder (approximate)"
    assert result.skipped == {} and result.stamps_ns.size == n and result.identical == n

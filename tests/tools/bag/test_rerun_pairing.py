"""``sappc rerun`` on bags of another controller node (no input stamps in diagnostics): the
recorded inputs go through the controller node's own pairing (:mod:`sappc_controller.inputs`),
the state the controller read is the fault relay's (:func:`~sappc_msgs_py.contract.consumed_names`),
and a sample with an input missing is skipped, never paired with a neighbour."""

from __future__ import annotations

import re
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


def test_a_real_time_bag_steps_each_state_with_the_reference_of_its_stamp_as_the_node_does(tmp_path: Path) -> None:
    """Real time (no /clock): the reference is published two frames ahead of the state; each
    state is stepped at its stamp with the reference of the same stamp, never a later one, and
    with the newest earlier one when its own never came (frame 12)."""
    controller, dt = _controller()
    messages = []
    dt_ns = round(dt * NS)
    t0_ns = 100 * NS  # epoch-like frames

    def reference(k: int) -> list[tuple[c.Topic, np.ndarray]]:
        return [(c.REFERENCE_ATTITUDE, np.array([0.0, 0.0, 0.0, 1.0])), (c.REFERENCE_RATE, np.array([0.001 * k, 0.0, 0.0])),
                (c.REFERENCE_ACCELERATION, np.zeros(3))]

    for k in range(2):  # the reference of frames 0 and 1 before the first state
        for topic, value in reference(k):
            messages.append((topic.name, topic.type_name, _msg(topic, value, (t0_ns + k * dt_ns) / NS), t0_ns - dt_ns // 2))
    expected = []
    for k in range(30):
        t_ns = t0_ns + k * dt_ns
        state = _inputs(k, t_ns / NS)[:2]
        for i, (topic, value) in enumerate(state):
            messages.append((topic.name, topic.type_name, _msg(topic, value, t_ns / NS), t_ns + 500_000 + i))
        used = reference(11 if k == 12 else k)
        expected.append(controller.step(t_ns / NS, dt, *(v for _, v in state), *(v for _, v in used)).torque_B)
        messages.append((c.CONTROL_TORQUE.name, c.CONTROL_TORQUE.type_name, torque_msg(expected[-1], t_ns / NS, c.CONTROL_TORQUE), t_ns + 2_000_000))
        if k + 2 != 12:  # mid-frame: the reference two frames ahead (frame 12's is lost)
            for topic, value in reference(k + 2):
                messages.append((topic.name, topic.type_name, _msg(topic, value, (t_ns + 2 * dt_ns) / NS), t_ns + dt_ns // 2))
    result = rerun_bag(read_bag(write_bag(tmp_path / "rt.mcap", messages)), PARAMS)
    assert result.mode == "realtime" and result.pairing == "the state's stamp, the reference received by then (approximate)"
    assert result.skipped == {} and result.stamps_ns.size == 30 and result.identical == 30


def test_rerun_exits_1_when_a_torque_differs_whatever_the_parameters(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """As ``--help`` says (issue 46): 0 only when every recomputed torque equals the recorded one,
    1 otherwise, with ``--params`` too (as diff: other gains give other torques, the expected
    answer of a what-if, which a script tests as ``|| test $? = 1``)."""
    import yaml

    from sappc.cli import main

    controller, dt = _controller()
    messages = []
    for k in range(20):
        t, log = k * dt, k * 10_000_000
        messages.append((c.CLOCK.name, c.CLOCK.type_name, clock_msg(t), log))
        inputs = _inputs(k, t)
        for i, (topic, value) in enumerate(inputs):
            messages.append((topic.name, topic.type_name, _msg(topic, value, t), log + i))
        torque = controller.step(t, dt, *(v for _, v in inputs)).torque_B
        messages.append((c.CONTROL_TORQUE.name, c.CONTROL_TORQUE.type_name, torque_msg(torque, t, c.CONTROL_TORQUE), log + 9))
    bag = write_bag(tmp_path / "run.mcap", messages)
    params = yaml.safe_load(PARAMS.read_text())
    params["/controller"]["ros__parameters"]["sappc"]["gains"]["K_q"] = 0.6
    stiffer = tmp_path / "stiffer.yaml"
    stiffer.write_text(yaml.safe_dump(params))
    assert main(["rerun", str(bag), "--params", str(PARAMS)]) == 0  # the parameters it flew with: every torque
    assert "identical torques: 20 of 20" in capsys.readouterr().out
    assert main(["rerun", str(bag), "--params", str(stiffer)]) == 1  # some torques the same (saturated), not all
    identical = re.search(r"identical torques: (\d+) of 20", capsys.readouterr().out)
    assert identical is not None and 0 < int(identical.group(1)) < 20

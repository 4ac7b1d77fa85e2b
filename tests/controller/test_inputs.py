"""The controller's input pairing (:mod:`sappc_controller.inputs`), the one rule that the node
and ``sappc rerun`` share: lockstep pairs the five inputs of one stamp (arrival order free, at most
``MAX_PENDING`` incomplete stamps); real time takes the latest input of each topic."""

from __future__ import annotations

import numpy as np

from sappc_controller.inputs import INPUT_TOPICS, MAX_PENDING, NS_PER_S, ControlSample, LatestInputs, LockstepPairing, step_sample
from sappc_controller.params import CONTROLLER_CLASSES, controller_from_parameters_file
from sappc_msgs_py.contract import CONTROLLER_INPUTS

from conftest import ROOT

Q0 = np.array([0.3254, 0.4068, -0.3254, 0.7891]) / np.linalg.norm([0.3254, 0.4068, -0.3254, 0.7891])
VALUES = (Q0, np.array([0.01, 0.0, -0.01]), np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(3))


def test_the_inputs_are_the_contracts_in_step_order() -> None:
    assert INPUT_TOPICS == CONTROLLER_INPUTS and len(INPUT_TOPICS) == 5


def test_lockstep_completes_a_sample_when_the_last_input_of_its_stamp_arrives_in_any_order() -> None:
    pairing = LockstepPairing()
    order = [3, 0, 4, 1]
    for i in order:
        assert pairing.add(INPUT_TOPICS[i].name, 20_000_000, VALUES[i]) is None
    assert pairing.add(INPUT_TOPICS[0].name, 10_000_000, VALUES[0]) is None  # another stamp waits apart
    sample = pairing.add(INPUT_TOPICS[2].name, 20_000_000, VALUES[2])
    assert sample is not None and sample.t_ns == 20_000_000 and sample.input_ns == (20_000_000,) * 5
    assert all(v is VALUES[i] for i, v in enumerate(sample.values))  # in step order, whatever the arrival
    assert pairing.pending == 1


def test_lockstep_drops_the_oldest_incomplete_stamp_beyond_max_pending() -> None:
    pairing = LockstepPairing()
    for k in range(MAX_PENDING + 1):
        pairing.add(INPUT_TOPICS[0].name, k, VALUES[0])
    assert pairing.pending == MAX_PENDING  # stamp 0 was dropped
    for i in range(1, 5):
        assert pairing.add(INPUT_TOPICS[i].name, 0, VALUES[i]) is None  # so its other inputs start over
    for i in range(1, 5):
        last = pairing.add(INPUT_TOPICS[i].name, 1, VALUES[i])
    assert last is not None and last.t_ns == 1


def test_real_time_takes_the_latest_input_of_each_topic_once_all_have_arrived() -> None:
    latest = LatestInputs()
    for i in range(4):
        latest.add(INPUT_TOPICS[i].name, 100 + i, VALUES[i])
    assert latest.sample_at(1_000) is None and not latest.complete
    latest.add(INPUT_TOPICS[4].name, 104, VALUES[4])
    latest.add(INPUT_TOPICS[1].name, 200, 2 * VALUES[1])  # replaces the older rate
    sample = latest.sample_at(1_000)
    assert sample is not None and sample.t_ns == 1_000 and sample.input_ns == (100, 200, 102, 103, 104)
    assert np.array_equal(sample.values[1], 2 * VALUES[1]) and latest.oldest_ns == 100 and latest.last_ns(INPUT_TOPICS[1].name) == 200


def test_a_step_on_a_sample_is_the_cores_step_at_the_sample_time() -> None:
    kind, config, dt = controller_from_parameters_file((ROOT / "config" / "controller_sappc.yaml").read_text(), source="sappc")
    a, b = CONTROLLER_CLASSES[kind](config), CONTROLLER_CLASSES[kind](config)
    sample = ControlSample(30_000_000, (30_000_000,) * 5, VALUES)
    out = step_sample(a, dt, sample)
    ref = b.step(30_000_000 / NS_PER_S, dt, *VALUES)
    assert np.array_equal(out.torque_B, ref.torque_B) and sample.t_s == 0.03


def test_a_sample_is_an_immutable_record() -> None:
    """A ``ControlSample`` is handed from the pairing to the step (and by ``sappc rerun`` to its
    report): a frozen record, no step can change the time or the stamps of the inputs it used."""
    import dataclasses

    import pytest

    sample = ControlSample(30_000_000, (30_000_000,) * 5, VALUES)
    with pytest.raises(dataclasses.FrozenInstanceError):
        sample.t_ns = 0  # type: ignore[misc]

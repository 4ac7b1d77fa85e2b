"""The controller's input pairing (:mod:`sappc_controller.inputs`), the one rule that the node
and ``sappc rerun`` share: lockstep pairs the five inputs of one stamp (arrival order free, at most
``MAX_PENDING`` incomplete stamps); real time takes the latest input of each topic."""

from __future__ import annotations

import numpy as np

from sappc_controller.inputs import INPUT_TOPICS, MAX_PENDING, NS_PER_S, ControlSample, LockstepPairing, RealtimePairing, step_sample
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


def test_real_time_steps_each_fresh_state_with_the_reference_of_its_stamp_or_the_newest_earlier_one() -> None:
    """A sample when the attitude and rate of a new stamp are both in; each reference topic gives
    its value of that stamp (published ahead), else the newest earlier one, never a later one; no
    sample before every reference topic has one at or before the state; a stamp not newer than
    the last sample makes none."""
    rt = RealtimePairing()
    att, rate, ref_q, ref_w, ref_a = (t.name for t in INPUT_TOPICS)
    assert rt.add(att, 100, VALUES[0]) is None and rt.add(rate, 100, VALUES[1]) is None  # no reference yet: not started
    for stamp in (100, 110, 120):  # the reference published ahead
        rt.add(ref_q, stamp, VALUES[2])
        rt.add(ref_w, stamp, stamp * np.ones(3))
    rt.add(ref_a, 90, VALUES[4])  # the acceleration only up to 90
    assert rt.add(rate, 110, VALUES[1]) is None  # half a state
    sample = rt.add(att, 110, VALUES[0])
    assert sample is not None and sample.t_ns == 110 and sample.input_ns == (110, 110, 110, 110, 90)
    assert np.array_equal(sample.values[3], 110 * np.ones(3)) and sample.oldest_ns == 90  # the rate of 110, not 120's
    assert rt.last_sample_ns == 110 and rt.last_ns(ref_w) == 120
    assert rt.add(att, 105, VALUES[0]) is None and rt.add(rate, 105, VALUES[1]) is None  # older than the last sample: none
    rt.add(att, 130, VALUES[0])
    later = rt.add(rate, 130, 2 * VALUES[1])
    assert later is not None and later.input_ns == (130, 130, 120, 120, 90) and np.array_equal(later.values[1], 2 * VALUES[1])


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

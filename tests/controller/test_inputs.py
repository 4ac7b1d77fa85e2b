"""The controller's input pairing (:mod:`sappc_controller.inputs`), the one rule that the node
and ``sappc rerun`` share: lockstep pairs the five inputs of one stamp (arrival order free, at most
``MAX_PENDING`` incomplete stamps); real time steps each fresh state with the reference of its own
stamp (held only when that arrived invalid or at the caller's deadline)."""

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


def test_real_time_steps_each_fresh_state_with_the_reference_of_its_own_stamp() -> None:
    """A state is fresh when the attitude and rate of a new stamp are both in; it makes a sample
    once every reference topic has its value of that stamp (published ahead, or arriving after
    the state), never a later one's; a stamp not newer than the last sample makes none."""
    rt = RealtimePairing()
    att, rate, ref_q, ref_w, ref_a = (t.name for t in INPUT_TOPICS)
    assert rt.add(att, 100, VALUES[0]) is None and rt.add(rate, 100, VALUES[1]) is None  # no reference yet
    assert rt.waiting_ns == 100
    for stamp in (100, 110, 120):  # the reference published ahead (100's after its state: the run's first frame)
        rt.add(ref_q, stamp, VALUES[2])
        rt.add(ref_w, stamp, stamp * np.ones(3))
    first = rt.add(ref_a, 100, VALUES[4])  # the last input of 100: the waiting state is stepped
    assert first is not None and first.t_ns == 100 and first.input_ns == (100,) * 5 and rt.waiting_ns is None
    assert rt.add(rate, 110, VALUES[1]) is None  # half a state
    assert rt.add(att, 110, VALUES[0]) is None  # the acceleration of 110 is not in yet: it waits, not the one of 100
    sample = rt.add(ref_a, 110, 3 * VALUES[4])
    assert sample is not None and sample.t_ns == 110 and sample.input_ns == (110,) * 5
    assert np.array_equal(sample.values[3], 110 * np.ones(3))  # the rate of 110, not 120's
    assert rt.last_sample_ns == 110 and rt.last_ns(ref_w) == 120
    assert rt.add(att, 105, VALUES[0]) is None and rt.add(rate, 105, VALUES[1]) is None  # older than the last sample: none
    assert rt.waiting_ns is None


def test_real_time_holds_the_newest_earlier_reference_only_when_its_own_arrived_invalid_or_at_the_deadline() -> None:
    """A reference of the state's stamp that arrived invalid ("no data") is replaced at once by the
    newest valid earlier one; one that has not arrived is held only when the caller's deadline
    passes (take_held); a newer state replaces one still waiting; take_held without any earlier
    reference makes no sample (it keeps waiting)."""
    rt = RealtimePairing()
    att, rate, ref_q, ref_w, ref_a = (t.name for t in INPUT_TOPICS)
    assert rt.take_held() is None  # nothing waits
    for stamp in (100, 110):
        for name, v in ((ref_q, VALUES[2]), (ref_w, stamp * np.ones(3)), (ref_a, VALUES[4])):
            rt.add(name, stamp, v)
    rt.add(att, 120, VALUES[0])
    assert rt.add(rate, 120, VALUES[1]) is None and rt.waiting_ns == 120  # no reference of 120 yet
    held = rt.take_held()  # the deadline: the newest earlier one, 110's
    assert held is not None and held.input_ns == (120, 120, 110, 110, 110) and np.array_equal(held.values[3], 110 * np.ones(3))
    assert rt.waiting_ns is None and rt.take_held() is None
    rt.add(att, 130, VALUES[0])
    rt.add(rate, 130, VALUES[1])
    rt.add(ref_q, 130, VALUES[2])
    rt.add(ref_a, 130, VALUES[4])
    now = rt.add(ref_w, 130, None)  # the reference rate of 130 arrived invalid: held at once
    assert now is not None and now.input_ns == (130, 130, 130, 110, 130)
    rt.add(att, 140, VALUES[0])
    rt.add(rate, 140, VALUES[1])
    rt.add(att, 150, VALUES[0])
    assert rt.add(rate, 150, VALUES[1]) is None and rt.waiting_ns == 150  # the newer state replaces 140's
    assert rt.add(ref_q, 140, VALUES[2]) is None  # too late for 140, and not 150's
    none_yet = RealtimePairing()
    none_yet.add(att, 10, VALUES[0])
    none_yet.add(rate, 10, VALUES[1])
    assert none_yet.take_held() is None and none_yet.waiting_ns == 10  # no reference at all: it keeps waiting


def test_a_step_on_a_sample_is_the_cores_step_at_the_sample_time() -> None:
    kind, config, dt = controller_from_parameters_file((ROOT / "config" / "controller_sappc.yaml").read_text(), source="sappc")
    a, b = CONTROLLER_CLASSES[kind](config), CONTROLLER_CLASSES[kind](config)
    sample = ControlSample(30_000_000, (30_000_000,) * 5, VALUES)
    out = step_sample(a, dt, sample)
    ref = b.step(30_000_000 / NS_PER_S, dt, *VALUES)
    assert np.array_equal(out.torque_B, ref.torque_B) and sample.t_s == 0.03


def test_a_real_time_step_counted_from_its_origin_is_the_lockstep_step_bit_for_bit() -> None:
    """Real time counts the law's time from the first step's stamp (an epoch time): samples at
    f0 + k dt with origin f0 step exactly as lockstep's at k dt (an epoch time of ~1.7e9 s as a
    float is only good to 0.24 us, which the old t = stamp / 1e9 passed to the law)."""
    kind, config, dt = controller_from_parameters_file((ROOT / "config" / "controller_sappc.yaml").read_text(), source="sappc")
    lock, rt = (CONTROLLER_CLASSES[kind](config) for _ in range(2))
    f0_ns = 1_700_000_000_123_000_000
    for k in range(5):
        t_ns = k * 10_000_000
        a = step_sample(lock, dt, ControlSample(t_ns, (t_ns,) * 5, VALUES)).torque_B.copy()
        b = step_sample(rt, dt, ControlSample(f0_ns + t_ns, (f0_ns + t_ns,) * 5, VALUES), origin_ns=f0_ns).torque_B.copy()
        assert np.array_equal(a, b), k


def test_a_sample_is_an_immutable_record() -> None:
    """A ``ControlSample`` is handed from the pairing to the step (and by ``sappc rerun`` to its
    report): an immutable record (a named tuple), no step can change the time or the stamps of the
    inputs it used."""
    import pytest

    sample = ControlSample(30_000_000, (30_000_000,) * 5, VALUES)
    with pytest.raises(AttributeError):
        sample.t_ns = 0  # type: ignore[misc]

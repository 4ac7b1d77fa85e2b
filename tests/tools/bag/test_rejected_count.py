"""The controller's count of rejected inputs as ``sappc run`` reads it from a bag (issue 46, item 2:
"600 input messages rejected" printed where the node's own count was 602): the largest
``status[0]`` of every diagnostics message in the bag, not the last aligned sample's."""

from __future__ import annotations

import numpy as np

from bagmaker import write_bag
from sappc.bag.read import bag_run, read_bag
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import diagnostics_msg, quaternion_msg, vector3_msg


def _rows(rejected: float, answer: float) -> dict[str, np.ndarray]:
    rows = {label: np.zeros(3) for label in c.DIAGNOSTICS_LAYOUT[1:]}
    rows["status"] = np.array([rejected, 0.0, answer])
    return rows


def test_the_bags_count_of_rejected_inputs_is_the_largest_of_every_diagnostics_message(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Five samples (0 to 40 ms), diagnostics at four of them (the last state, its input rejected,
    had no step: no diagnostics of its stamp), the count growing 0, 1, 1, 2, and one more message
    after the run's span (60 ms, count 3): the run's count is 3, the last one the controller
    published, not 1 (the count at the last aligned sample with diagnostics) nor 2."""
    messages = []
    for k in range(7):
        t = k * 0.01
        messages += [(c.STATE_ATTITUDE.name, c.STATE_ATTITUDE.type_name, quaternion_msg([0.0, 0.0, 0.0, 1.0], t, c.STATE_ATTITUDE), 10 * k),
                     (c.STATE_RATE.name, c.STATE_RATE.type_name, vector3_msg([0.0, 0.0, 0.0], t, c.STATE_RATE), 10 * k + 1),
                     (c.REFERENCE_ATTITUDE.name, c.REFERENCE_ATTITUDE.type_name, quaternion_msg([0.0, 0.0, 0.0, 1.0], t, c.REFERENCE_ATTITUDE),
                      10 * k + 2)]
    for k, rejected in ((0, 0.0), (1, 1.0), (2, 1.0), (3, 2.0), (6, 3.0)):
        messages.append((c.CONTROLLER_DIAGNOSTICS.name, c.CONTROLLER_DIAGNOSTICS.type_name,
                         diagnostics_msg(k * 0.01, _rows(rejected, float(c.ANSWER_COMMANDED))), 10 * k + 3))
    bag = read_bag(write_bag(tmp_path / "run.mcap", messages))
    run = bag_run(bag, duration_s=0.04)
    assert run.answer.tolist() == [c.ANSWER_COMMANDED] * 4 + [c.ANSWER_HELD]  # sample 4: no diagnostics of its stamp
    assert run.rejected == 3 and run.controller_summary()["rejected_inputs"] == 3
    none = read_bag(write_bag(tmp_path / "none.mcap", [m for m in messages if m[0] != c.CONTROLLER_DIAGNOSTICS.name]))
    assert bag_run(none).rejected == 0

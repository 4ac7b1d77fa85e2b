"""The per-message fast paths (one quaternion checked in Python floats, encoders filling a reused
message) decide and write exactly what the general numpy paths do."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gnc_common.validation import QUATERNION_NORM_TOL, InputError, check_unit_quaternion


def test_one_quaternion_is_judged_as_the_batch_path_judges_it_at_the_tolerance(rng) -> None:  # type: ignore[no-untyped-def]
    q = rng.standard_normal((2000, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    scales = 1.0 + QUATERNION_NORM_TOL * rng.uniform(0.98, 1.02, 2000) * rng.choice([-1.0, 1.0], 2000)  # around the boundary
    for row in q * scales[:, None]:
        try:
            check_unit_quaternion("q", row[None, :])  # the batch path
            batch_ok = True
        except InputError:
            batch_ok = False
        try:
            assert check_unit_quaternion("q", row) is row  # the one-quaternion path returns its input
            one_ok = True
        except InputError:
            one_ok = False
        assert one_ok == batch_ok, row


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_one_non_finite_quaternion_is_refused_naming_the_value(bad: float) -> None:
    with pytest.raises(InputError, match=r"^q contains a non-finite value"):
        check_unit_quaternion("q", np.array([0.0, 0.0, bad, 1.0]))


def test_encoders_fill_a_reused_message_as_they_build_a_new_one() -> None:
    """Compared field by field after a round trip through the serializer (its alignment padding is
    uninitialised memory, tests/tools/bag/test_cdr_padding.py, so bytes may differ there)."""
    from rclpy.serialization import deserialize_message, serialize_message

    from sappc_msgs_py import contract as c
    from sappc_msgs_py.convert import clock_msg, diagnostics_msg, quaternion_msg, torque_msg, vector3_msg

    rows = {k: [1.0, 2.0, 3.0] for k in c.DIAGNOSTICS_LAYOUT[1:]}
    reused = {t.name: t.msg_class() for t in (c.STATE_ATTITUDE, c.STATE_RATE, c.CONTROL_TORQUE, c.CONTROLLER_DIAGNOSTICS, c.CLOCK)}
    for k, t in enumerate((0.0, 0.01, 1234.56789)):  # refilled: nothing of the previous message remains
        q = np.array([0.1, -0.2, 0.3, math.sqrt(1 - 0.14)]) * (1 if k % 2 else -1)
        w = [0.1 * k, -0.2, 1e-9]
        pairs = [
            (quaternion_msg(q, t, c.STATE_ATTITUDE), quaternion_msg(q, t, c.STATE_ATTITUDE, out=reused[c.STATE_ATTITUDE.name])),
            (vector3_msg(w, t, c.STATE_RATE), vector3_msg(w, t, c.STATE_RATE, out=reused[c.STATE_RATE.name])),
            (torque_msg(np.array(w), t), torque_msg(np.array(w), t, out=reused[c.CONTROL_TORQUE.name])),
            (diagnostics_msg(t, rows), diagnostics_msg(t, rows, out=reused[c.CONTROLLER_DIAGNOSTICS.name])),
            (clock_msg(t), clock_msg(t, out=reused[c.CLOCK.name])),
        ]
        for new, filled in pairs:
            assert deserialize_message(serialize_message(filled), type(new)) == new, (k, type(new).__name__)
    with pytest.raises(InputError, match=r"^state/rate vector contains a non-finite value nan"):
        vector3_msg([0.0, math.nan, 0.0], 0.0, c.STATE_RATE, out=reused[c.STATE_RATE.name])
    with pytest.raises(InputError, match=r"^t_s contains a non-finite value"):
        vector3_msg([0.0, 0.0, 0.0], math.inf, c.STATE_RATE)
